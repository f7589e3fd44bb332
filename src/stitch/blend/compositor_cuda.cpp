#include "stitch/blend/compositor_cuda.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <stdexcept>

#include "../../../cuda/blend/seam_kernels.hpp"
#include "stitch/blend/seam_cuda.hpp"
#include "stitch/cuda/cuda_util.hpp"
#include "stitch/cuda/view_geometry.hpp"

namespace stitch {

struct CudaComposer::State {
  CudaStream stream;
  std::vector<stitch_cuda::ViewGeometry> views;
  std::vector<DeviceBuffer> inputs;
  DeviceBuffer output, canvas;
  int out_w = 0, out_h = 0;
  // Texture objects over the input frames, a few per view: buffer pools hand frames round a
  // few buffers, and making a texture object costs host time on every frame otherwise.
  struct CachedTexture {
    stitch_cuda::DeviceImage image;
    unsigned long long texture = 0;
    std::uint64_t used = 0;
  };
  static constexpr std::size_t kTexturesPerView = 8;
  std::vector<std::vector<CachedTexture>> textures;
  std::uint64_t texture_clock = 0;
  // Multiband: the blender, and the camera frames warped into their rectangles.
  BlendMode mode = BlendMode::Weighted;
  int bands = MultibandBlender::kDefaultBands;
  std::unique_ptr<MultibandBlender> multiband;
  std::vector<DeviceBuffer> warped;
  // The fuse's tiles (launch_fuse_tiles): made at the first fuse after prepare().
  DeviceBuffer tiles;
  bool tiles_made = false;
  const uint8_t* fuse_tiles() {
    if (!tiles_made) {
      tiles.resize(stitch_cuda::fuse_tile_count(out_w, out_h));
      stitch_cuda::launch_fuse_tiles(int(views.size()), views.data(), out_w, out_h, tiles.data(), stream.get());
      tiles_made = true;
    }
    return tiles.data();
  }
  // Seam finding: its settings and the finder.
  bool find_seams = false;
  SeamSettings seam_settings;
  std::unique_ptr<SeamFinderCuda> seam;

  // Blends device views with multiband, cutting the masks along this frame's seams first.
  void multiband_fuse(const std::vector<ImageView>& views, const ImageView& out) {
    stream.sync();  // uploads and warps done: the seam finder and the blender have their own streams
    if (seam) multiband->set_labels(seam->find(views), /*on_device=*/true);
    multiband->fuse(views, out);
  }
  // Views warped into their device rectangles first: multiband, or the consensus blend.
  bool needs_rects() const { return multiband || seam; }
  // The consensus blend (weighted mean + seams): the weighted mean of the views, then where
  // they disagree the seam's view (SeamFinder::mix, stitch::seam::mix_value).
  void consensus_fuse(const std::vector<ImageView>& views, const ImageView& out) {
    const uint8_t* labels = seam->find(views, stream.get());  // in this stream's order: no host wait
    std::vector<stitch_cuda::DeviceImage> images(views.size());
    for (std::size_t i = 0; i < views.size(); ++i)
      if (!views[i].empty()) images[i] = to_device_image(views[i]);
    const stitch_cuda::DeviceImage d = to_device_image(out);
    // The weighted mean and, where the views disagree, the seam's view: one pass over the output.
    stitch_cuda::launch_fuse(int(images.size()), this->views.data(), images.data(), d, stream.get(), labels,
                             seam->mix_map(), d.width == out_w && d.height == out_h ? fuse_tiles() : nullptr);
  }
  void rect_fuse(const std::vector<ImageView>& views, const ImageView& out) {
    if (multiband)
      multiband_fuse(views, out);
    else
      consensus_fuse(views, out);
  }

  ~State() {
    for (auto& view : textures)
      for (auto& t : view) stitch_cuda::destroy_texture(t.texture);
  }
  unsigned long long texture_of(std::size_t view, const stitch_cuda::DeviceImage& d) {
    std::vector<CachedTexture>& cache = textures[view];
    ++texture_clock;
    for (CachedTexture& t : cache) {
      const stitch_cuda::DeviceImage& k = t.image;
      if (k.data == d.data && k.pitch == d.pitch && k.width == d.width && k.height == d.height) {
        t.used = texture_clock;
        return t.texture;
      }
    }
    if (cache.size() == kTexturesPerView) {  // the least recently used goes
      auto oldest = std::min_element(cache.begin(), cache.end(),
                                     [](const CachedTexture& a, const CachedTexture& b) { return a.used < b.used; });
      stitch_cuda::destroy_texture(oldest->texture);
      cache.erase(oldest);
    }
    cache.push_back({d, stitch_cuda::create_rgba_texture(d), texture_clock});
    return cache.back().texture;
  }
  // Textures for every present frame, or false when one cannot have a texture (alignment).
  bool texture_all(const std::vector<stitch_cuda::DeviceImage>& images, std::vector<unsigned long long>& out) {
    textures.resize(images.size());
    out.assign(images.size(), 0);
    for (std::size_t i = 0; i < images.size(); ++i) {
      if (!images[i].data) continue;
      out[i] = texture_of(i, images[i]);
      if (!out[i]) return false;
    }
    return true;
  }

  // Per view: how many times its frame is halved (ViewPlacement::level), and the halved copies.
  std::vector<int> levels;
  std::vector<std::vector<DeviceBuffer>> reduced;
  stitch_cuda::DeviceImage on_device(const ImageView& v, std::size_t slot) {
    return reduce_on_device(device_image_of(v, inputs[slot], stream.get()), slot < levels.size() ? levels[slot] : 0,
                            reduced[slot], stream.get());
  }
  stitch_cuda::DeviceImage target(const ImageView& out) {
    if (out.width != out_w || out.height != out_h) throw std::invalid_argument("output size differs from prepare()");
    if (out.on_device) return to_device_image(out);
    output.resize(std::size_t(out_w) * out_h * 4);
    stitch_cuda::DeviceImage d;
    d.data = output.data();
    d.pitch = std::size_t(out_w) * 4;
    d.width = out_w;
    d.height = out_h;
    return d;
  }
  static ImageView device_view(const stitch_cuda::DeviceImage& d) {
    return ImageView{d.data, d.pitch, d.width, d.height, PixelFormat::RGBA8, true};
  }
  // The blender's views: the present ones, already in device memory (empty: missing).
  static std::vector<ImageView> device_views(const std::vector<stitch_cuda::DeviceImage>& images) {
    std::vector<ImageView> d(images.size());
    for (std::size_t i = 0; i < images.size(); ++i)
      if (images[i].data) d[i] = device_view(images[i]);
    return d;
  }
  void finish(const ImageView& out, const stitch_cuda::DeviceImage& d) {
    if (!out.on_device) {
      STITCH_CUDA(cudaMemcpy2DAsync(out.data, out.pitch, d.data, d.pitch, std::size_t(out_w) * 4, out_h,
                                    cudaMemcpyDeviceToHost, stream.get()));
      stream.sync();  // the host reads it
    } else {
      stream.leave();  // handed on by event when the element installed a hand-off
    }
  }
};

CudaComposer::CudaComposer() : s_(std::make_unique<State>()) {}
CudaComposer::~CudaComposer() = default;

void CudaComposer::set_blend_mode(BlendMode mode, int bands, const SeamSettings* seams) {
  s_->mode = mode;
  s_->bands = bands;
  s_->find_seams = seams != nullptr;
  if (seams) s_->seam_settings = *seams;
}

void CudaComposer::prepare(const std::vector<ViewPlacement>& views, int out_width, int out_height) {
  if (views.size() > std::size_t(stitch_cuda::kMaxViews)) throw std::invalid_argument("at most 16 views on the GPU");
  s_->multiband.reset();
  if (s_->mode == BlendMode::Multiband) {
    s_->multiband = MultibandBlender::create(Backend::Cuda, s_->bands);
    s_->multiband->prepare(views, out_width, out_height);
    s_->warped.resize(views.size());
  }
  s_->seam.reset();
  if (s_->find_seams) {  // multiband's masks, or the consensus blend
    s_->warped.resize(views.size());
    s_->seam = std::make_unique<SeamFinderCuda>(s_->seam_settings);
    s_->seam->prepare(views, out_width, out_height);
  }
  s_->views.clear();
  s_->levels.clear();
  for (const auto& v : views) {
    s_->views.push_back(to_device_geometry(v));
    s_->levels.push_back(v.level);
  }
  s_->reduced.resize(views.size());
  s_->inputs.resize(views.size());
  s_->out_w = out_width;
  s_->out_h = out_height;
  s_->tiles_made = false;
}

void CudaComposer::compose(const std::vector<ImageView>& frames, const ImageView& out, const float* color) {
  if (frames.size() != s_->views.size()) throw std::invalid_argument("view count differs from prepare()");
  s_->stream.enter();
  std::vector<stitch_cuda::DeviceImage> images(frames.size());
  for (std::size_t i = 0; i < frames.size(); ++i)
    if (!frames[i].empty() && s_->views[i].roi_w > 0) images[i] = s_->on_device(frames[i], i);
  const stitch_cuda::DeviceImage d = s_->target(out);
  if (s_->needs_rects()) {
    if (color) throw std::invalid_argument("multiband or seam compose takes no color matrices");
    std::vector<ImageView> warped(frames.size());
    std::vector<stitch_cuda::DeviceImage> rects(frames.size());
    std::vector<uint8_t*> lumas(frames.size(), nullptr);
    for (std::size_t i = 0; i < frames.size(); ++i) {
      const stitch_cuda::ViewGeometry& g = s_->views[i];
      if (!images[i].data) continue;
      stitch_cuda::DeviceImage& w = rects[i];
      w.width = g.roi_w;
      w.height = g.roi_h;
      w.pitch = std::size_t(g.roi_w) * 4;
      s_->warped[i].resize(w.pitch * w.height);
      w.data = s_->warped[i].data();
      // The seam finder's luma of the view in the same pass: find() then need not read it again.
      lumas[i] = s_->seam ? s_->seam->luma_for_next_find(i) : nullptr;
      warped[i] = s_->device_view(w);
    }
    // Every view in one launch, with the texture units' bilinear taps where the frames allow them.
    std::vector<unsigned long long> tex;
    const bool textured = s_->texture_all(images, tex);
    stitch_cuda::launch_warps(int(frames.size()), images.data(), s_->views.data(), rects.data(), lumas.data(),
                              textured ? tex.data() : nullptr, s_->stream.get());
    s_->rect_fuse(warped, s_->device_view(d));
    s_->finish(out, d);
    return;
  }
  std::vector<unsigned long long> tex;
  // Tiles one view covers alone take its sample without the weights (the fuse's tiles).
  const uint8_t* tiles = d.width == s_->out_w && d.height == s_->out_h ? s_->fuse_tiles() : nullptr;
  if (s_->texture_all(images, tex))
    stitch_cuda::launch_compose_tex(int(images.size()), s_->views.data(), tex.data(), color, d, s_->stream.get(), tiles);
  else
    stitch_cuda::launch_compose(int(images.size()), s_->views.data(), images.data(), color, d, s_->stream.get(), tiles);
  s_->finish(out, d);
}

void CudaComposer::fuse_resampled(const std::vector<ImageView>& views, const ImageView& out,
                                  const double canvas_to_output[6]) {
  if (views.size() != s_->views.size()) throw std::invalid_argument("view count differs from prepare()");
  s_->stream.enter();
  std::vector<stitch_cuda::DeviceImage> images(views.size());
  for (std::size_t i = 0; i < views.size(); ++i)
    if (!views[i].empty() && s_->views[i].roi_w > 0) images[i] = s_->on_device(views[i], i);
  stitch_cuda::DeviceImage canvas;
  canvas.width = s_->out_w;
  canvas.height = s_->out_h;
  canvas.pitch = std::size_t(canvas.width) * 4;
  s_->canvas.resize(canvas.pitch * canvas.height);
  canvas.data = s_->canvas.data();
  if (s_->needs_rects()) {
    s_->rect_fuse(s_->device_views(images), s_->device_view(canvas));
  } else {
    stitch_cuda::launch_fuse(int(images.size()), s_->views.data(), images.data(), canvas, s_->stream.get(), nullptr,
                             nullptr, s_->fuse_tiles());
  }
  // Invert the (scale + translation) affine: dst pixel -> canvas pixel.
  const double a = canvas_to_output[0], b = canvas_to_output[1], c = canvas_to_output[2];
  const double d = canvas_to_output[3], e = canvas_to_output[4], f = canvas_to_output[5];
  const double det = a * e - b * d;
  if (std::abs(det) < 1e-12) throw std::invalid_argument("degenerate canvas-to-output transform");
  const float inv[6] = {float(e / det), float(-b / det), float((b * f - c * e) / det),
                        float(-d / det), float(a / det), float((c * d - a * f) / det)};
  stitch_cuda::DeviceImage d_out;
  if (out.on_device) {
    d_out = to_device_image(out);
  } else {
    s_->output.resize(std::size_t(out.width) * out.height * 4);
    d_out.data = s_->output.data();
    d_out.pitch = std::size_t(out.width) * 4;
    d_out.width = out.width;
    d_out.height = out.height;
  }
  stitch_cuda::launch_resample_affine(canvas, inv, d_out, s_->stream.get());
  if (!out.on_device) {
    STITCH_CUDA(cudaMemcpy2DAsync(out.data, out.pitch, d_out.data, d_out.pitch, std::size_t(out.width) * 4,
                                  out.height, cudaMemcpyDeviceToHost, s_->stream.get()));
    s_->stream.sync();
  } else {
    s_->stream.leave();
  }
}

void CudaComposer::fuse(const std::vector<ImageView>& views, const ImageView& out) {
  if (views.size() != s_->views.size()) throw std::invalid_argument("view count differs from prepare()");
  s_->stream.enter();
  std::vector<stitch_cuda::DeviceImage> images(views.size());
  for (std::size_t i = 0; i < views.size(); ++i)
    if (!views[i].empty() && s_->views[i].roi_w > 0) images[i] = s_->on_device(views[i], i);
  const stitch_cuda::DeviceImage d = s_->target(out);
  if (s_->needs_rects()) {
    s_->rect_fuse(s_->device_views(images), s_->device_view(d));
  } else {
    stitch_cuda::launch_fuse(int(images.size()), s_->views.data(), images.data(), d, s_->stream.get(), nullptr, nullptr,
                             s_->fuse_tiles());
  }
  s_->finish(out, d);
}

}  // namespace stitch

namespace stitch {

std::vector<uint8_t> CudaComposer::seam_labels() const {
  return s_->seam ? s_->seam->labels() : std::vector<uint8_t>();
}

void CudaComposer::draw_on_host(const ImageView& out, const std::function<void(const ImageView&)>& draw) {
  if (!out.on_device) {
    draw(out);
    return;
  }
  s_->stream.sync();  // the panorama may still be in flight (stream-ordered hand-off)
  const std::size_t pitch = std::size_t(out.width) * 4;
  std::vector<uint8_t> host(pitch * out.height);
  STITCH_CUDA(cudaMemcpy2D(host.data(), pitch, out.data, out.pitch, pitch, out.height, cudaMemcpyDeviceToHost));
  draw(ImageView{host.data(), pitch, out.width, out.height, PixelFormat::RGBA8, false});
  STITCH_CUDA(cudaMemcpy2D(out.data, out.pitch, host.data(), pitch, pitch, out.height, cudaMemcpyHostToDevice));
  STITCH_CUDA(cudaStreamSynchronize(cudaStreamLegacy));  // the DMA from pageable memory may still run
}

}  // namespace stitch
