// Dense optical flow: a known smooth displacement of a real image is recovered; identical
// and uniform images give zero flow; the CPU algorithm is chosen by this measurement.
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <opencv2/imgproc.hpp>

#include "stitch/flow/flow.hpp"
#include "test_data.hpp"

#include "flow_fields.hpp"

using namespace stitch;

namespace {

using testdata::displace;
using testdata::smooth_field;

cv::Mat gray_photo(const std::string& path, cv::Size size) {
  cv::Mat rgba = testdata::load_rgba(path), g;
  cv::cvtColor(rgba, g, cv::COLOR_RGBA2GRAY);
  cv::resize(g, g, size, 0, 0, cv::INTER_AREA);
  return g;
}

std::vector<std::string> photos() {
  std::vector<std::string> p = {testdata::repo_path("data/photos/boat1_1600.jpg")};
  const std::string shared = testdata::shared_path("images/udis2_carpark_dhw/input1.jpg");
  if (!shared.empty()) p.push_back(shared);
  return p;
}

}  // namespace

TEST(DenseFlow, KnownSmoothDisplacementIsRecovered) {
  for (const auto& path : photos()) {
    const cv::Mat from = gray_photo(path, cv::Size(480, 360));
    // Flow from -> to is the field itself: to(x + f(x)) = from(x).
    const cv::Mat field = smooth_field(from.size(), 4.0);
    const cv::Mat to = displace(from, field);
    cv::Mat mask(from.size(), CV_8U, cv::Scalar(0));
    mask(cv::Rect(16, 16, from.cols - 32, from.rows - 32)).setTo(255);  // borders have no match
    for (FlowAlgorithm a : {FlowAlgorithm::Dis, FlowAlgorithm::Farneback}) {
      auto flow = DenseFlow::create(Backend::Cpu, a, FlowQuality::Medium);
      cv::Mat f;
      const auto t0 = std::chrono::steady_clock::now();
      flow->compute(from, to, f, false);
      const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
      const double epe = median_endpoint_error(f, field, mask);
      std::printf("%s %s: median EPE %.3f px, %.1f ms (480x360)\n", path.c_str(),
                  a == FlowAlgorithm::Dis ? "DIS" : "Farneback", epe, ms);
      EXPECT_LT(epe, 0.5) << path;
    }
  }
}

TEST(DenseFlow, IdenticalViewsGiveZeroFlow) {
  const cv::Mat img = gray_photo(photos()[0], cv::Size(320, 240));
  for (FlowAlgorithm a : {FlowAlgorithm::Dis, FlowAlgorithm::Farneback}) {
    auto flow = DenseFlow::create(Backend::Cpu, a, FlowQuality::Medium);
    cv::Mat f;
    flow->compute(img, img, f, false);
    EXPECT_LT(median_endpoint_error(f, cv::Mat::zeros(f.size(), CV_32FC2)), 0.05);
  }
}

TEST(DenseFlow, UniformAndBlackFramesGiveZeroFlowWithoutNaN) {
  for (int level : {0, 128, 255}) {
    cv::Mat a(120, 160, CV_8U, cv::Scalar(level)), b(120, 160, CV_8U, cv::Scalar(level));
    for (FlowAlgorithm alg : {FlowAlgorithm::Dis, FlowAlgorithm::Farneback}) {
      auto flow = DenseFlow::create(Backend::Cpu, alg, FlowQuality::Fast);
      cv::Mat f;
      flow->compute(a, b, f, false);
      ASSERT_EQ(f.type(), CV_32FC2);
      EXPECT_TRUE(cv::checkRange(f));
      EXPECT_EQ(cv::countNonZero(f.reshape(1)), 0);
    }
  }
}

TEST(DenseFlow, FlowNeverPointsOutsideTheImage) {
  const cv::Mat from = gray_photo(photos()[0], cv::Size(200, 150));
  cv::Mat shifted;
  cv::Mat M = (cv::Mat_<double>(2, 3) << 1, 0, 12, 0, 1, 0);
  cv::warpAffine(from, shifted, M, from.size(), cv::INTER_LINEAR, cv::BORDER_REPLICATE);
  auto flow = DenseFlow::create(Backend::Cpu, FlowAlgorithm::Dis, FlowQuality::Medium);
  cv::Mat f;
  flow->compute(from, shifted, f, false);
  for (int y = 0; y < f.rows; ++y)
    for (int x = 0; x < f.cols; ++x) {
      const cv::Vec2f d = f.at<cv::Vec2f>(y, x);
      ASSERT_GE(x + d[0], -1e-3);
      ASSERT_LE(x + d[0], f.cols - 1 + 1e-3);
      ASSERT_GE(y + d[1], -1e-3);
      ASSERT_LE(y + d[1], f.rows - 1 + 1e-3);
    }
}
