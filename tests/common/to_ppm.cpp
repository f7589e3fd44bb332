// Build helper: decodes an image (JPEG, PNG, ...) to a binary PPM for test_cuda and
// stitch-bench-cuda, which read frames without OpenCV's imgcodecs.
#include <cstdio>
#include <opencv2/imgcodecs.hpp>

int main(int argc, char** argv) {
  if (argc != 3) {
    std::fprintf(stderr, "usage: %s IN OUT.ppm\n", argv[0]);
    return 2;
  }
  const cv::Mat img = cv::imread(argv[1], cv::IMREAD_COLOR);
  if (img.empty() || !cv::imwrite(argv[2], img)) {
    std::fprintf(stderr, "cannot convert %s to %s\n", argv[1], argv[2]);
    return 1;
  }
  return 0;
}
