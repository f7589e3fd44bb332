#include <opencv2/core.hpp>
#include <stdexcept>

#include "stitch/color/color.hpp"
#include "stitch/cv_interop.hpp"

#ifdef STITCH_HAVE_CUDA
#include "stitch/cuda/stages_cuda.hpp"
#endif

namespace stitch {
namespace {

class ColorOpsCpu final : public ColorOps {
 public:
  void gather(const ImageView& view, const std::vector<int32_t>& xy,
              std::vector<std::array<uint8_t, 3>>& out) override {
    out.resize(xy.size() / 2);
    for (std::size_t k = 0; k < out.size(); ++k) {
      const uint8_t* p = view.row(xy[2 * k + 1]) + 4 * xy[2 * k];
      out[k] = {p[0], p[1], p[2]};
    }
  }

  void apply(const ImageView& view, const Eigen::Matrix3d& M,
             const std::array<std::array<uint8_t, 256>, 3>& lut) override {
    cv::Mat img = as_mat(view);
    if (!M.isIdentity(1e-9)) {
      // out_c = sum_k in_k M(k, c): cv::transform's matrix is M transposed; alpha passes.
      cv::Matx44f T = cv::Matx44f::eye();
      for (int c = 0; c < 3; ++c)
        for (int k = 0; k < 3; ++k) T(c, k) = float(M(k, c));
      cv::transform(img, img, T);
    }
    bool identity = true;
    for (int c = 0; c < 3 && identity; ++c)
      for (int v = 0; v < 256 && identity; ++v) identity = lut[c][v] == v;
    if (identity) return;
    cv::Mat table(1, 256, CV_8UC4);
    for (int v = 0; v < 256; ++v) table.at<cv::Vec4b>(0, v) = {lut[0][v], lut[1][v], lut[2][v], uint8_t(v)};
    cv::LUT(img, table, img);
  }

  Backend backend() const override { return Backend::Cpu; }
};

}  // namespace

std::unique_ptr<ColorOps> ColorOps::create(Backend backend) {
  switch (resolve_backend(backend, /*stage_has_cuda=*/true)) {
#ifdef STITCH_HAVE_CUDA
    case Backend::Cuda: return make_color_ops_cuda();
#endif
    case Backend::Cpu: return std::make_unique<ColorOpsCpu>();
    default: break;
  }
  throw std::runtime_error("no color stage for this backend");
}

}  // namespace stitch
