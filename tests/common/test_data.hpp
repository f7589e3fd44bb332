// Where test data lives: the repository's own data/ always, ../shared/data when present.
#pragma once
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "image_compare.hpp"
#include "synthetic_rig.hpp"
#include "stitch/rig/rig.hpp"

namespace testdata {

std::string source_dir();                  // repository root
std::string repo_path(const std::string& rel);  // repository root / rel
// ../shared/data/<rel>, or "" when the shared data is not there.
std::string shared_path(const std::string& rel);
std::string temp_dir();                    // a fresh folder for this process
// RGBA image from a file (OpenCV reads BGR); throws when missing.
cv::Mat load_rgba(const std::string& path);

// Two 640x480 crops of data/photos/boat1_1600.jpg, 400 px apart from row 200, and their exact
// calibration saved as temp_dir()/`file`: the panorama is the photo's 1040x480 band.
struct BoatCrops {
  cv::Mat photo;
  std::vector<cv::Mat> views;
  std::string calib;
};
inline BoatCrops boat_crops(const std::string& file) {
  BoatCrops c;
  c.photo = load_rgba(repo_path("data/photos/boat1_1600.jpg"));
  for (int i = 0; i < 2; ++i) c.views.push_back(c.photo(cv::Rect(400 * i, 200, 640, 480)).clone());
  c.calib = temp_dir() + "/" + file;
  stitch::rig_save(shifted_rig(2, 640, 480, 400), c.calib);
  return c;
}

}  // namespace testdata
