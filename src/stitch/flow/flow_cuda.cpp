// GPU dense flow: pyramidal dense Lucas-Kanade (cuda/flow/flow_math.cuh has the per-pixel
// math and why it averages per-pixel constraints), all pairs of a call in the same launches.
#include "stitch/flow/flow_cuda.hpp"

#include <algorithm>
#include <array>
#include <stdexcept>
#include <string>

#include "../../../cuda/flow/flow_kernels.hpp"
#include "stitch/cuda/cuda_util.hpp"

namespace stitch {
namespace {

// Six levels: a 1080p overlap at the flow's half resolution (~540 rows) still has a level of
// 17 rows, where two passes of at most 1 px reach 64 px of the full resolution and more.
constexpr int kMaxLevels = 6;

struct LkSettings {
  int max_levels = kMaxLevels;
  int min_level_side = 16;       // no pyramid level whose smaller side is below this
  int coarse_iterations = 2;     // passes per level above the finest
  int fine_iterations = 3;       // passes at full resolution (>= 2, see compute())
  int initial_start_level = 3;   // with a previous field: refine from this level (capture range
                                 // ~30 px of the flow image around it, so an object that enters
                                 // an overlap with 60 px of disparity is caught; fewer launches
                                 // than the full pyramid)
  float lambda = 1.f;
  float max_step = 1.f;
};

// Measured with the kernels' math on the host (boat photo, 480x360, smooth 4 px field): median
// error 0.107 / 0.102 / 0.101 px for Fast / Medium / Fine (the CPU DIS of the same quality:
// 0.297 / 0.225 / 0.101). More passes buy robustness on real overlaps, not accuracy here (with
// noise they even fit it a little: sigma 4 grey levels gave 0.25 / 0.27 / 0.28 px).
LkSettings settings_for(FlowQuality q) {
  LkSettings s;
  switch (q) {
    case FlowQuality::Fast: s.coarse_iterations = 1, s.fine_iterations = 2; break;
    case FlowQuality::Medium: s.coarse_iterations = 2, s.fine_iterations = 3; break;
    case FlowQuality::Fine: s.coarse_iterations = 3, s.fine_iterations = 3; break;
  }
  return s;
}

constexpr std::size_t kAlign = 256;
std::size_t align_up(std::size_t v, std::size_t a) { return (v + a - 1) / a * a; }
int pitch_for(int width) { return int(align_up(std::size_t(width), 32)); }  // elements

// Where one pair's working images live in the arena (byte offsets) and how they are sized.
struct PairLayout {
  int start_level = 0;  // coarsest level refined
  std::array<int, kMaxLevels> w{}, h{}, pitch{};
  std::array<std::size_t, kMaxLevels> from{}, to{};  // float pyramid levels >= 1
  std::array<std::array<std::size_t, 2>, kMaxLevels> flow{};  // ping-pong flows per level
};

class CudaDenseFlowImpl final : public CudaDenseFlow {
 public:
  explicit CudaDenseFlowImpl(FlowQuality q) : s_(settings_for(q)) {
    if (s_.fine_iterations < 2 || s_.coarse_iterations < 1 || s_.max_levels > kMaxLevels)
      throw std::logic_error("dense flow settings out of range");
  }

  void compute(const std::vector<DeviceFlowTask>& tasks, cudaStream_t stream) override {
    const int n = int(tasks.size());
    if (n == 0) return;
    if (n > stitch_cuda::kMaxFlowTasks) throw std::invalid_argument("CUDA dense flow: at most 32 pairs per call");
    for (const DeviceFlowTask& t : tasks) validate(t);

    // Layout of every pair's pyramid and flows, then the statistics and flags.
    std::size_t bytes = 0;
    auto take = [&bytes](std::size_t b) {
      const std::size_t at = bytes;
      bytes = align_up(bytes + b, kAlign);
      return at;
    };
    layouts_.resize(std::size_t(n));
    int top = 0, max_w1 = 1, max_h1 = 1;
    for (int i = 0; i < n; ++i) {
      PairLayout& L = layouts_[std::size_t(i)];
      const DeviceFlowTask& t = tasks[std::size_t(i)];
      const int levels = level_count(t.width, t.height);
      L.start_level = t.use_initial ? std::min(levels - 1, s_.initial_start_level) : levels - 1;
      top = std::max(top, L.start_level);
      for (int l = 0; l <= L.start_level; ++l) {
        L.w[l] = l == 0 ? t.width : (L.w[l - 1] + 1) / 2;
        L.h[l] = l == 0 ? t.height : (L.h[l - 1] + 1) / 2;
        L.pitch[l] = pitch_for(L.w[l]);
        const std::size_t plane = std::size_t(L.pitch[l]) * std::size_t(L.h[l]) * sizeof(float);
        if (l > 0) {
          L.from[l] = take(plane);
          L.to[l] = take(plane);
        }
        L.flow[l][0] = take(2 * plane);
        L.flow[l][1] = take(2 * plane);
      }
      max_w1 = std::max(max_w1, (t.width + 1) / 2);
      max_h1 = std::max(max_h1, (t.height + 1) / 2);
    }
    const int stats_blocks = stitch_cuda::flow_stats_blocks_per_image(max_w1, max_h1);
    const std::size_t stats_at = take(std::size_t(2 * n) * std::size_t(stats_blocks) * 2 * sizeof(uint32_t));
    const std::size_t flat_at = take(std::size_t(n) * sizeof(int));
    arena_.resize(bytes);  // grows only: no allocation once the sizes repeat
    uint8_t* base = arena_.data();
    auto plane_at = [base](std::size_t off) { return reinterpret_cast<float*>(base + off); };
    uint32_t* stats = reinterpret_cast<uint32_t*>(base + stats_at);
    int* flat = reinterpret_cast<int*>(base + flat_at);

    // Pyramids; the first step also measures whether an image is flat (CPU flows' rule).
    std::array<stitch_cuda::FlowPyramidImage, 2 * stitch_cuda::kMaxFlowTasks> images{};
    std::array<int, stitch_cuda::kMaxFlowTasks> pixels{};
    for (int level = 1; level <= std::max(top, 1); ++level) {
      for (int i = 0; i < n; ++i) {
        const PairLayout& L = layouts_[std::size_t(i)];
        const DeviceFlowTask& t = tasks[std::size_t(i)];
        const bool wanted = level <= L.start_level;
        for (int k = 0; k < 2; ++k) {
          stitch_cuda::FlowPyramidImage& im = images[std::size_t(2 * i + k)];
          im = {};
          if (level == 1) {
            im.src = k == 0 ? t.from : t.to;
            im.src_pitch = int(t.gray_pitch);
            im.src_w = t.width, im.src_h = t.height;
            im.dst_w = (t.width + 1) / 2, im.dst_h = (t.height + 1) / 2;
          } else if (wanted) {
            im.src = plane_at(k == 0 ? L.from[level - 1] : L.to[level - 1]);
            im.src_pitch = L.pitch[level - 1];
            im.src_w = L.w[level - 1], im.src_h = L.h[level - 1];
            im.dst_w = L.w[level], im.dst_h = L.h[level];
          }
          if (wanted) {
            im.dst = plane_at(k == 0 ? L.from[level] : L.to[level]);
            im.dst_pitch = L.pitch[level];
          }
        }
        pixels[std::size_t(i)] = t.width * t.height;
      }
      if (level == 1) {
        stitch_cuda::launch_flow_pyramid_first(n, images.data(), stats, stats_blocks, stream);
        stitch_cuda::launch_flow_flatness(n, stats, stats_blocks, pixels.data(), flat, stream);
      } else {
        stitch_cuda::launch_flow_pyramid(n, images.data(), stream);
      }
    }

    // Coarse to fine: each level starts from the coarser result (or zero / the caller's
    // field at a pair's start level), then refines in place by ping-pong passes; the last pass
    // at full resolution writes the caller's flow.
    std::array<stitch_cuda::FlowLevelTask, stitch_cuda::kMaxFlowTasks> passes{}, seeds{};
    for (int level = top; level >= 0; --level) {
      const int iterations = level == 0 ? s_.fine_iterations : s_.coarse_iterations;
      for (int k = 0; k < iterations; ++k) {
        const bool final_pass = level == 0 && k == iterations - 1;
        int seed_w = 0, seed_h = 0;
        for (int i = 0; i < n; ++i) {
          const PairLayout& L = layouts_[std::size_t(i)];
          const DeviceFlowTask& t = tasks[std::size_t(i)];
          stitch_cuda::FlowLevelTask& p = passes[std::size_t(i)];
          p = {};
          if (level > L.start_level) continue;  // kFlowSkip
          p.width = L.w[level], p.height = L.h[level];
          if (level == 0) {
            p.from = t.from, p.to = t.to;
            p.image_pitch = int(t.gray_pitch);
          } else {
            p.from = plane_at(L.from[level]), p.to = plane_at(L.to[level]);
            p.image_pitch = L.pitch[level];
          }
          if (k > 0) {
            p.source = stitch_cuda::kFlowCurrent;
            p.src = plane_at(L.flow[level][std::size_t((k - 1) % 2)]);
            p.src_pitch = L.pitch[level];
            p.src_w = L.w[level], p.src_h = L.h[level];
          } else if (level < L.start_level) {
            const int coarse_iterations = s_.coarse_iterations;  // every level above 0 has these
            p.source = stitch_cuda::kFlowUpsample;
            p.src = plane_at(L.flow[level + 1][std::size_t((coarse_iterations - 1) % 2)]);
            p.src_pitch = L.pitch[level + 1];
            p.src_w = L.w[level + 1], p.src_h = L.h[level + 1];
          } else if (t.use_initial) {
            // Read only by this first pass; the caller's buffer is written by the final pass,
            // a later launch (fine_iterations >= 2).
            p.source = stitch_cuda::kFlowSeed;
            p.src = t.flow;
            p.src_pitch = int(t.flow_pitch / (2 * sizeof(float)));
            p.src_w = t.width, p.src_h = t.height;
            p.seed_step = 1 << level;
            if (!final_pass) {
              // averaged down once into the buffer this pass does not write (it writes [0])
              stitch_cuda::FlowLevelTask& seed = seeds[std::size_t(i)];
              seed = p;
              seed.width = L.w[level], seed.height = L.h[level];
              seed.dst = plane_at(L.flow[level][1]);
              seed.dst_pitch = L.pitch[level];
              seed_w = std::max(seed_w, seed.width), seed_h = std::max(seed_h, seed.height);
              p.source = stitch_cuda::kFlowCurrent;
              p.src = seed.dst;
              p.src_pitch = L.pitch[level];
              p.src_w = L.w[level], p.src_h = L.h[level];
            }
          } else {
            p.source = stitch_cuda::kFlowZero;
          }
          if (final_pass) {
            p.dst = t.flow;
            p.dst_pitch = int(t.flow_pitch / (2 * sizeof(float)));
          } else {
            p.dst = plane_at(L.flow[level][std::size_t(k % 2)]);
            p.dst_pitch = L.pitch[level];
          }
        }
        if (seed_w > 0) {
          stitch_cuda::launch_flow_seed(n, seeds.data(), seed_w, seed_h, stream);
          seeds = {};  // kFlowSkip for the next seeding
        }
        stitch_cuda::FlowIterationSettings it;
        it.lambda = s_.lambda;
        it.max_step = s_.max_step;
        it.level0 = level == 0;
        it.final_pass = final_pass;
        it.flat = flat;
        stitch_cuda::launch_flow_iteration(n, passes.data(), it, stream);
      }
    }
  }

 private:
  static void validate(const DeviceFlowTask& t) {
    if (!t.from || !t.to || !t.flow || t.width <= 0 || t.height <= 0)
      throw std::invalid_argument("CUDA dense flow: a task without images, flow or size");
    if (t.gray_pitch < std::size_t(t.width) || t.flow_pitch < std::size_t(t.width) * 2 * sizeof(float) ||
        t.flow_pitch % (2 * sizeof(float)) != 0 || reinterpret_cast<uintptr_t>(t.flow) % sizeof(float) != 0)
      throw std::invalid_argument("CUDA dense flow: pitch smaller than a row, or flow pitch not whole (u, v) pairs");
    if (t.width > 65535 || t.height > 65535 || std::size_t(t.width) * std::size_t(t.height) > (1u << 28) ||
        t.gray_pitch > (1u << 30) || t.flow_pitch > (1u << 30))
      throw std::invalid_argument("CUDA dense flow: image too large");
  }

  int level_count(int w, int h) const {
    int levels = 1;
    while (levels < s_.max_levels) {
      w = (w + 1) / 2, h = (h + 1) / 2;
      if (std::min(w, h) < s_.min_level_side) break;
      ++levels;
    }
    return levels;
  }

  LkSettings s_;
  DeviceBuffer arena_;
  std::vector<PairLayout> layouts_;
};

// The host (cv::Mat) interface: one pair, uploaded and downloaded on an own stream.
class DenseFlowCudaHost final : public DenseFlow {
 public:
  explicit DenseFlowCudaHost(FlowQuality q) : flow_(CudaDenseFlow::create(q)) {}

  void compute(const cv::Mat& from, const cv::Mat& to, cv::Mat& flow, bool use_initial) override {
    if (from.type() != CV_8UC1 || to.type() != CV_8UC1 || from.size() != to.size() || from.empty())
      throw std::invalid_argument("dense flow needs two 8-bit grayscale images of the same size");
    const bool init = use_initial && flow.size() == from.size() && flow.type() == CV_32FC2;
    if (!init) flow.create(from.size(), CV_32FC2);
    const int w = from.cols, h = from.rows;
    const std::size_t gray_pitch = align_up(std::size_t(w), kAlign), flow_pitch = std::size_t(w) * 2 * sizeof(float);
    gray_.resize(2 * gray_pitch * std::size_t(h));
    field_.resize(flow_pitch * std::size_t(h));
    uint8_t* d_from = gray_.data();
    uint8_t* d_to = gray_.data() + gray_pitch * std::size_t(h);
    const cudaStream_t s = stream_.get();
    STITCH_CUDA(cudaMemcpy2DAsync(d_from, gray_pitch, from.data, from.step, std::size_t(w), std::size_t(h),
                                  cudaMemcpyHostToDevice, s));
    STITCH_CUDA(cudaMemcpy2DAsync(d_to, gray_pitch, to.data, to.step, std::size_t(w), std::size_t(h),
                                  cudaMemcpyHostToDevice, s));
    if (init)
      STITCH_CUDA(cudaMemcpy2DAsync(field_.data(), flow_pitch, flow.data, flow.step, flow_pitch, std::size_t(h),
                                    cudaMemcpyHostToDevice, s));
    DeviceFlowTask t;
    t.from = d_from;
    t.to = d_to;
    t.gray_pitch = gray_pitch;
    t.width = w;
    t.height = h;
    t.flow = reinterpret_cast<float*>(field_.data());
    t.flow_pitch = flow_pitch;
    t.use_initial = init;
    flow_->compute({t}, s);
    STITCH_CUDA(cudaMemcpy2DAsync(flow.data, flow.step, field_.data(), flow_pitch, flow_pitch, std::size_t(h),
                                  cudaMemcpyDeviceToHost, s));
    stream_.sync();
  }

  Backend backend() const override { return Backend::Cuda; }

 private:
  std::unique_ptr<CudaDenseFlow> flow_;
  CudaStream stream_;
  DeviceBuffer gray_, field_;
};

}  // namespace

std::unique_ptr<CudaDenseFlow> CudaDenseFlow::create(FlowQuality quality) {
  return std::make_unique<CudaDenseFlowImpl>(quality);
}

std::unique_ptr<DenseFlow> make_dense_flow_cuda(FlowQuality quality) {
  return std::make_unique<DenseFlowCudaHost>(quality);
}

}  // namespace stitch
