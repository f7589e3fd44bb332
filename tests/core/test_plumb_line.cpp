// Per-camera plumb-line lenses (issue 15, mixed rigs): plumb_line.hpp.
#include <gtest/gtest.h>

#include <cstdlib>
#include <opencv2/imgcodecs.hpp>
#include <sstream>

#include "stitch/calib/plumb_line.hpp"
#include "stitch/cv_interop.hpp"
#include "test_data.hpp"

using namespace stitch;

// PLUMB_FRAMES="a.png b.png ...": print each frame's plumb-line lens (a measuring aid).
TEST(PlumbLine, Probe) {
  const char* env = std::getenv("PLUMB_FRAMES");
  if (!env) GTEST_SKIP() << "PLUMB_FRAMES not set";
  std::istringstream in(env);
  std::string path;
  while (in >> path) {
    cv::Mat m = testdata::load_rgba(path);
    ASSERT_FALSE(m.empty()) << path;
    const auto t0 = cv::getTickCount();
    const PlumbLineLens l = plumb_line_lens({as_view(m)});
    std::printf("%s: %s%s (%.2f s)\n", path.c_str(), l.found ? "" : "NOT FOUND ", l.describe().c_str(),
                double(cv::getTickCount() - t0) / cv::getTickFrequency());
  }
}
