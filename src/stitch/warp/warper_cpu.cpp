#include <Eigen/Core>
#include <opencv2/imgproc.hpp>
#include <stdexcept>

#include "stitch/warp/warper.hpp"
#include "stitch/warp/warper_cpu.hpp"

#ifdef STITCH_HAVE_CUDA
#include "stitch/cuda/stages_cuda.hpp"
#endif

namespace stitch {

void camera_maps(const ViewPlacement& v, const Rect& part, const cv::Mat& displacement,
                 cv::Mat& map_x, cv::Mat& map_y) {
  map_x.create(part.height, part.width, CV_32F);
  map_y.create(part.height, part.width, CV_32F);
  const bool moved = !displacement.empty();
  cv::parallel_for_(cv::Range(0, part.height), [&](const cv::Range& r) {
    for (int y = r.start; y < r.end; ++y) {
      float* px = map_x.ptr<float>(y);
      float* py = map_y.ptr<float>(y);
      const cv::Vec2f* pd = moved ? displacement.ptr<cv::Vec2f>(y) : nullptr;
      for (int x = 0; x < part.width; ++x) {
        double ox = v.roi.x + part.x + x, oy = v.roi.y + part.y + y;
        if (pd) {
          ox += pd[x][0];
          oy += pd[x][1];
        }
        double u, w;
        const bool ok = view_to_camera(v, ox, oy, u, w);
        px[x] = ok ? float(u) : -1e6f;
        py[x] = ok ? float(w) : -1e6f;
      }
    }
  });
}

void WarperCpu::prepare(const std::vector<ViewPlacement>& views) {
  maps_.assign(views.size(), {});
  for (std::size_t i = 0; i < views.size(); ++i) {
    const ViewPlacement& v = views[i];
    if (v.roi.empty()) continue;
    cv::Mat fx, fy;
    camera_maps(v, {0, 0, v.roi.width, v.roi.height}, cv::Mat(), fx, fy);
    // Fixed-point maps: remap is about twice as fast with them and the error is < 1/32 px.
    cv::convertMaps(fx, fy, maps_[i].xy, maps_[i].frac, CV_16SC2);
  }
}

void WarperCpu::warp(int index, const ImageView& src, const ImageView& dst) {
  if (src.on_device || dst.on_device) throw std::invalid_argument("CPU warper got device memory");
  const Maps& m = maps_.at(static_cast<std::size_t>(index));
  if (m.xy.empty()) return;
  if (dst.width != m.xy.cols || dst.height != m.xy.rows)
    throw std::invalid_argument("warp destination does not match the view's rectangle");
  cv::Mat s(src.height, src.width, CV_8UC4, src.data, src.pitch);
  cv::Mat d(dst.height, dst.width, CV_8UC4, dst.data, dst.pitch);
  cv::remap(s, d, m.xy, m.frac, cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar::all(0));
}

void WarperCpu::warp_part(int index, const ImageView& src, const ImageView& dst, const Rect& part) {
  if (src.on_device || dst.on_device) throw std::invalid_argument("CPU warper got device memory");
  const Maps& m = maps_.at(static_cast<std::size_t>(index));
  if (m.xy.empty() || part.empty()) return;
  if (dst.width != m.xy.cols || dst.height != m.xy.rows)
    throw std::invalid_argument("warp destination does not match the view's rectangle");
  const cv::Rect r(part.x, part.y, part.width, part.height);
  if ((r & cv::Rect(0, 0, dst.width, dst.height)) != r) throw std::invalid_argument("warp part outside the view");
  cv::Mat s(src.height, src.width, CV_8UC4, src.data, src.pitch);
  cv::Mat d = cv::Mat(dst.height, dst.width, CV_8UC4, dst.data, dst.pitch)(r);
  cv::remap(s, d, m.xy(r), m.frac(r), cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar::all(0));
}

void WarperCpu::warp_part_to(int index, const ImageView& src, const Rect& part, uint8_t* dst, std::size_t pitch) {
  if (src.on_device) throw std::invalid_argument("CPU warper got device memory");
  const Maps& m = maps_.at(static_cast<std::size_t>(index));
  if (m.xy.empty() || part.empty()) return;
  const cv::Rect r(part.x, part.y, part.width, part.height);
  if ((r & cv::Rect(0, 0, m.xy.cols, m.xy.rows)) != r) throw std::invalid_argument("warp part outside the view");
  cv::Mat s(src.height, src.width, CV_8UC4, src.data, src.pitch);
  cv::Mat d(part.height, part.width, CV_8UC4, dst, pitch);
  cv::remap(s, d, m.xy(r), m.frac(r), cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar::all(0));
}

std::unique_ptr<Warper> Warper::create(Backend backend) {
  switch (resolve_backend(backend, /*stage_has_cuda=*/true)) {
#ifdef STITCH_HAVE_CUDA
    case Backend::Cuda: return make_warper_cuda();
#endif
    case Backend::Cpu: return std::make_unique<WarperCpu>();
    default: break;
  }
  throw std::runtime_error("no warper for this backend");
}

}  // namespace stitch
