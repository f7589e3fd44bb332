// Where test data lives: the repository's own data/ always, ../shared/data when present.
#pragma once
#include <opencv2/core.hpp>
#include <string>

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


}  // namespace testdata
