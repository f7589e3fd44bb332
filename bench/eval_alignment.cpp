// Independent check of a saved calibration on real clips: the median canvas distance between
// the two ends of SIFT matches (fundamental-matrix RANSAC inliers) in every overlap.
// usage: stitch-eval-alignment CALIB.json FRAME_INDEX CLIP0 CLIP1 [...]
#include <cstdio>
#include <cstdlib>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>

#include "stitch/calib/calibrator.hpp"
#include "stitch/cv_interop.hpp"

int main(int argc, char** argv) {
  if (argc < 5) {
    std::fprintf(stderr, "usage: %s CALIB.json FRAME_INDEX CLIP0 CLIP1 [...]\n", argv[0]);
    return 2;
  }
  try {
    stitch::Rig rig = stitch::rig_load(argv[1]);
    const int index = std::atoi(argv[2]);
    std::vector<cv::Mat> frames;
    std::vector<stitch::ImageView> views;
    for (int i = 3; i < argc; ++i) {
      const std::string path = argv[i];
      const std::string ext = path.substr(path.find_last_of('.') + 1);
      if (ext == "jpg" || ext == "JPG" || ext == "jpeg" || ext == "png" || ext == "ppm") {
        // An image set: one frame per camera, whatever the index.
        cv::Mat f = cv::imread(path, cv::IMREAD_COLOR);
        if (f.empty()) {
          std::fprintf(stderr, "%s: cannot read the image\n", argv[i]);
          return 1;
        }
        cv::cvtColor(f, f, cv::COLOR_BGR2RGBA);
        frames.push_back(f);
        continue;
      }
      cv::VideoCapture cap(argv[i]);
      cv::Mat f;
      for (int k = 0; k <= index; ++k)
        if (!cap.read(f)) {
          std::fprintf(stderr, "%s: cannot read frame %d\n", argv[i], k);
          return 1;
        }
      cv::cvtColor(f, f, cv::COLOR_BGR2RGBA);
      frames.push_back(f);
    }
    for (auto& f : frames) views.push_back(stitch::as_view(f));
    const stitch::AlignmentReport r = stitch::measure_alignment(rig, views);
    std::printf("alignment median %.3f px p90 %.3f px over %d matches;", r.median_px, r.p90_px, r.matches);
    for (double p : r.pair_median_px) std::printf(" pair %.3f", p);
    std::printf("\n");
    return r.median_px < 0 ? 1 : 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return 1;
  }
}
