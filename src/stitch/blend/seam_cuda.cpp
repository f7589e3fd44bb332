#include "stitch/blend/seam_cuda.hpp"

#include <cstring>
#include <stdexcept>

#include "../../../cuda/blend/seam_kernels.hpp"
#include "stitch/blend/multiband.hpp"
#include "stitch/cuda/cuda_util.hpp"
#include "stitch/cuda/view_geometry.hpp"

namespace stitch {

struct SeamFinderCuda::State {
  SeamFinder planner;  // the pairs and their centre costs (geometry only)
  std::vector<ViewPlacement> views;
  int width = 0, height = 0;
  struct PairState {
    stitch_cuda::SeamPairGeometry geometry;
    int rows = 0, cols = 0;
    DeviceBuffer centre, cost, steps, path, previous, diff, across, edge;  // diff, across: window sums
    DeviceBuffer levels;  // the pair's own mix levels (the view-switch cost, label_hold > 0)
    DeviceBuffer counts;  // the overlap's pixels, and the dark ones of a and b (a blank view loses the overlap)
    bool has_previous = false, cut = false;
  };
  std::vector<PairState> pairs;
  std::vector<DeviceBuffer> luma, previous_luma;
  std::vector<bool> has_luma;
  std::vector<bool> luma_given;  // luma_for_next_find(i) since the last find()
  DeviceBuffer labels, nearest, mix;  // mix: the consensus blend's levels (mix_radius > 0)
  DeviceBuffer previous_labels;       // last find()'s labels (label_hold > 0)
  bool has_labels = false;            // a find() since prepare()
  DeviceBuffer jobs;                   // the DP jobs of the cut pairs, uploaded when they change
  std::vector<stitch_cuda::SeamDpJob> host_jobs, uploaded_jobs;
  uint64_t nearest_mask = ~uint64_t(0);
  CudaStream stream;
  explicit State(const SeamSettings& s) : planner(s) {}
};

SeamFinderCuda::SeamFinderCuda(const SeamSettings& settings) : s_(std::make_unique<State>(settings)) {}
SeamFinderCuda::~SeamFinderCuda() = default;

const std::vector<SeamFinder::Pair>& SeamFinderCuda::pairs() const { return s_->planner.pairs(); }

uint8_t* SeamFinderCuda::luma_for_next_find(std::size_t i) {
  State& s = *s_;
  if (i >= s.luma.size()) throw std::out_of_range("seam luma: no such view");
  if (!s.luma_given[i]) {  // this frame's luma goes where the frame before last's was
    std::swap(s.luma[i], s.previous_luma[i]);
    s.luma_given[i] = true;
  }
  return s.luma[i].data();
}

void SeamFinderCuda::prepare(const std::vector<ViewPlacement>& views, int width, int height) {
  s_->planner.prepare(views, width, height);
  s_->views = views;
  s_->width = width;
  s_->height = height;
  s_->pairs.clear();
  for (const SeamFinder::Pair& p : s_->planner.pairs()) {
    State::PairState ps;
    stitch_cuda::SeamPairGeometry& g = ps.geometry;
    g.a = p.a;
    g.b = p.b;
    g.vertical = p.vertical;
    g.box_x = p.box.x, g.box_y = p.box.y, g.box_w = p.box.width, g.box_h = p.box.height;
    const Rect &ra = views[p.a].roi, &rb = views[p.b].roi;
    const int roi_a[4] = {ra.x, ra.y, ra.width, ra.height}, roi_b[4] = {rb.x, rb.y, rb.width, rb.height};
    std::copy(roi_a, roi_a + 4, g.roi_a);
    std::copy(roi_b, roi_b + 4, g.roi_b);
    ps.rows = p.vertical ? p.box.height : p.box.width;
    ps.cols = p.vertical ? p.box.width : p.box.height;
    const std::size_t cells = std::size_t(ps.rows) * ps.cols;
    ps.centre.resize(cells * sizeof(float));
    STITCH_CUDA(cudaMemcpy(ps.centre.data(), p.centre_cost.data(), cells * sizeof(float), cudaMemcpyHostToDevice));
    ps.cost.resize(cells * sizeof(float));
    ps.diff.resize(cells * sizeof(int));
    ps.across.resize(cells * sizeof(int));
    ps.steps.resize(cells);
    if (s_->planner.settings().label_hold > 0.f) ps.levels.resize(cells);
    ps.edge.resize((2 * std::size_t(ps.cols) + 2) * sizeof(float));
    ps.path.resize(ps.rows * sizeof(int));
    ps.previous.resize(ps.rows * sizeof(int));
    ps.counts.resize(3 * sizeof(int));
    s_->pairs.push_back(std::move(ps));
  }
  s_->luma.clear();
  s_->previous_luma.clear();
  for (const ViewPlacement& v : views) {
    const std::size_t px = v.roi.empty() ? 1 : std::size_t(v.roi.width) * v.roi.height;
    s_->luma.emplace_back(px);
    s_->previous_luma.emplace_back(px);
  }
  s_->has_luma.assign(views.size(), false);
  s_->luma_given.assign(views.size(), false);
  s_->labels.resize(std::size_t(width) * height);
  if (s_->planner.settings().label_hold > 0.f) s_->previous_labels.resize(std::size_t(width) * height);
  s_->has_labels = false;
  if (s_->planner.settings().mix_radius > 0) s_->mix.resize(std::size_t(width) * height);
  s_->nearest.resize(std::size_t(width) * height);
  s_->nearest_mask = ~uint64_t(0);
}

const uint8_t* SeamFinderCuda::find(const std::vector<ImageView>& warped, cudaStream_t stream) {
  State& s = *s_;
  if (warped.size() != s.views.size()) throw std::invalid_argument("view count differs from prepare()");
  const cudaStream_t st = stream ? stream : s.stream.get();
  uint64_t mask = 0;
  for (std::size_t i = 0; i < warped.size(); ++i) {
    const bool given = s.luma_given[i];
    s.luma_given[i] = false;
    if (warped[i].empty() || s.views[i].roi.empty()) {
      s.has_luma[i] = false;
      continue;
    }
    if (!warped[i].on_device) throw std::invalid_argument("the CUDA seam finder reads views in device memory");
    mask |= uint64_t(1) << i;
    if (!given) {
      std::swap(s.luma[i], s.previous_luma[i]);
      stitch_cuda::launch_seam_luma(to_device_image(warped[i]), s.luma[i].data(), st);
    }
    if (!s.has_luma[i])  // no previous frame: no motion
      STITCH_CUDA(cudaMemcpyAsync(s.previous_luma[i].data(), s.luma[i].data(),
                                  std::size_t(warped[i].width) * warped[i].height, cudaMemcpyDeviceToDevice, st));
    s.has_luma[i] = true;
  }
  if (mask != s.nearest_mask) {
    const std::vector<uint8_t> nearest = nearest_view_labels(s.views, s.width, s.height, mask);
    STITCH_CUDA(cudaMemcpyAsync(s.nearest.data(), nearest.data(), nearest.size(), cudaMemcpyHostToDevice, st));
    STITCH_CUDA(cudaStreamSynchronize(st));  // `nearest` is a host temporary
    s.nearest_mask = mask;
  }
  const SeamSettings& settings = s.planner.settings();
  const bool holding = settings.label_hold > 0.f && settings.mix_radius > 0 && s.has_labels;
  if (holding)  // last frame's labels, for the view-switch cost (as SeamFinder::find's swap)
    STITCH_CUDA(cudaMemcpyAsync(s.previous_labels.data(), s.labels.data(), std::size_t(s.width) * s.height,
                                cudaMemcpyDeviceToDevice, st));
  STITCH_CUDA(cudaMemcpyAsync(s.labels.data(), s.nearest.data(), std::size_t(s.width) * s.height,
                              cudaMemcpyDeviceToDevice, st));
  const seam::Weights w{settings.difference_weight, settings.edge_weight, settings.motion_weight, settings.stability,
                        settings.hold, settings.clearance_weight, settings.clearance_radius,
                        settings.mix_radius, settings.agree_level, settings.disagree_level, settings.crossing_weight,
                        settings.centre_weight, settings.label_hold};
  if (w.mix_radius > 0) STITCH_CUDA(cudaMemsetAsync(s.mix.data(), 0, std::size_t(s.width) * s.height, st));
  // Costs of every cut pair, then all their DP sweeps in one launch, then the labels pair by pair
  // (in the CPU's order: boxes of different pairs may overlap).
  s.host_jobs.clear();
  int max_cols = 1;
  for (State::PairState& p : s.pairs) {
    const int a = p.geometry.a, b = p.geometry.b;
    p.cut = (mask >> a & 1) && (mask >> b & 1);
    if (!p.cut) {
      p.has_previous = false;
      continue;
    }
    STITCH_CUDA(cudaMemsetAsync(p.counts.data(), 0, 3 * sizeof(int), st));
    stitch_cuda::launch_seam_cost(p.geometry, to_device_image(warped[a]), to_device_image(warped[b]),
                                  s.luma[a].data(), s.luma[b].data(), s.previous_luma[a].data(),
                                  s.previous_luma[b].data(), reinterpret_cast<const float*>(p.centre.data()), w,
                                  reinterpret_cast<float*>(p.cost.data()), reinterpret_cast<int*>(p.diff.data()),
                                  reinterpret_cast<int*>(p.across.data()), reinterpret_cast<int*>(p.counts.data()), st);
    // the mix levels, and from them the crossing cost, before the DP reads the costs
    stitch_cuda::launch_seam_mix(p.geometry, reinterpret_cast<const int*>(p.diff.data()),
                                 reinterpret_cast<int*>(p.across.data()), reinterpret_cast<const float*>(p.centre.data()),
                                 w, reinterpret_cast<const int*>(p.counts.data()), reinterpret_cast<float*>(p.cost.data()),
                                 s.mix.data(), s.width, p.levels.size() ? p.levels.data() : nullptr,
                                 holding && p.has_previous ? s.previous_labels.data() : nullptr, st);
    s.host_jobs.push_back({reinterpret_cast<const float*>(p.cost.data()), p.rows, p.cols,
                           p.has_previous ? reinterpret_cast<const int*>(p.previous.data()) : nullptr,
                           reinterpret_cast<int8_t*>(p.steps.data()), reinterpret_cast<int*>(p.path.data()),
                           reinterpret_cast<float*>(p.edge.data())});
    max_cols = std::max(max_cols, p.cols);
  }
  if (!s.host_jobs.empty()) {
    const std::size_t bytes = s.host_jobs.size() * sizeof(stitch_cuda::SeamDpJob);
    // The jobs change only when a pair gains or loses its previous path (a camera comes or
    // goes): an upload from pageable memory may wait for the stream, so it is not made per frame.
    if (s.uploaded_jobs.size() != s.host_jobs.size() ||
        std::memcmp(s.uploaded_jobs.data(), s.host_jobs.data(), bytes) != 0) {
      s.jobs.resize(bytes);
      STITCH_CUDA(cudaMemcpyAsync(s.jobs.data(), s.host_jobs.data(), bytes, cudaMemcpyHostToDevice, st));
      STITCH_CUDA(cudaStreamSynchronize(st));  // the source is host memory that changes
      s.uploaded_jobs = s.host_jobs;
    }
    stitch_cuda::launch_seam_dp(reinterpret_cast<const stitch_cuda::SeamDpJob*>(s.jobs.data()), int(s.host_jobs.size()),
                                max_cols, w.stability, w.hold, st);
  }
  for (State::PairState& p : s.pairs) {
    if (!p.cut) continue;
    stitch_cuda::launch_seam_labels(s.labels.data(), s.width, p.geometry, reinterpret_cast<const float*>(p.centre.data()),
                                    reinterpret_cast<const int*>(p.path.data()),
                                    reinterpret_cast<const int*>(p.counts.data()), st);
    STITCH_CUDA(cudaMemcpyAsync(p.previous.data(), p.path.data(), p.rows * sizeof(int), cudaMemcpyDeviceToDevice, st));
    p.has_previous = true;
  }
  s.has_labels = true;
  if (!stream) s.stream.sync();
  return s.labels.data();
}

std::vector<uint8_t> SeamFinderCuda::labels() const {
  std::vector<uint8_t> out(std::size_t(s_->width) * s_->height);
  STITCH_CUDA(cudaMemcpy(out.data(), s_->labels.data(), out.size(), cudaMemcpyDeviceToHost));
  return out;
}

const uint8_t* SeamFinderCuda::mix_map() const { return s_->mix.size() ? s_->mix.data() : nullptr; }

std::vector<uint8_t> SeamFinderCuda::mix() const {
  if (!s_->mix.size()) return {};
  std::vector<uint8_t> out(std::size_t(s_->width) * s_->height);
  STITCH_CUDA(cudaMemcpy(out.data(), s_->mix.data(), out.size(), cudaMemcpyDeviceToHost));
  return out;
}

std::vector<std::vector<int>> SeamFinderCuda::paths() const {
  std::vector<std::vector<int>> out;
  for (const State::PairState& p : s_->pairs) {
    out.emplace_back();
    if (!p.cut) continue;
    out.back().resize(p.rows);
    STITCH_CUDA(cudaMemcpy(out.back().data(), p.path.data(), p.rows * sizeof(int), cudaMemcpyDeviceToHost));
  }
  return out;
}

}  // namespace stitch
