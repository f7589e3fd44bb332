#include <algorithm>
#include <cmath>
#include <opencv2/imgproc.hpp>
#include <stdexcept>
#include <chrono>
#include <cstdio>
#include <cstdlib>

#include "stitch/blend/blender_cpu.hpp"
#include "stitch/warp/flow_gate_math.hpp"
#include "stitch/parallel.hpp"
#include "stitch/warp/flow_pairs.hpp"
#include "stitch/warp/flow_warper.hpp"
#include "stitch/warp/warper_cpu.hpp"

#ifdef STITCH_HAVE_CUDA
#include "stitch/cuda/stages_cuda.hpp"
#endif

namespace stitch {
namespace {

constexpr float kNegligiblePx = 1.f / 32.f;  // below remap's sub-pixel resolution

cv::Rect to_cv(const Rect& r) { return {r.x, r.y, r.width, r.height}; }

Rect bounding(const Rect& a, const Rect& b) {
  const int x0 = std::min(a.x, b.x), y0 = std::min(a.y, b.y);
  const int x1 = std::max(a.x + a.width, b.x + b.width), y1 = std::max(a.y + a.height, b.y + b.height);
  return {x0, y0, x1 - x0, y1 - y0};
}

Rect shifted(const Rect& r, int dx, int dy) { return {r.x + dx, r.y + dy, r.width, r.height}; }

cv::Mat as_mat(const ImageView& v) { return cv::Mat(v.height, v.width, CV_8UC4, v.data, v.pitch); }

// f(y) for every row 0..n-1 on OpenCV's threads. Per-pixel work only, so results do not
// depend on the split. Inside another parallel_for_ OpenCV runs it serially.
template <class F>
void for_rows(int n, const F& f) {
  cv::parallel_for_(cv::Range(0, n), [&](const cv::Range& r) {
    for (int y = r.start; y < r.end; ++y) f(y);
  });
}

// Row strips [y0, y1) of n rows on OpenCV's threads, for whole-image OpenCV calls split by
// rows: pointwise operations, and float filters on row ROIs, which read the rows around a
// strip from the parent matrix, so the values equal the whole-image call's at any split.
// (OpenCV's GaussianBlur, convertTo, multiply and setTo run on one thread.)
template <class F>
void in_strips(int n, const F& f) {
  const int strips = std::max(1, std::min(n / 8, 4 * cv::getNumThreads()));
  cv::parallel_for_(cv::Range(0, strips), [&](const cv::Range& r) {
    for (int i = r.start; i < r.end; ++i)
      f(int(int64_t(n) * i / strips), int(int64_t(n) * (i + 1) / strips));
  });
}

// in_strips over several images in one parallel loop (one wait for the threads): f(image, y0, y1).
template <class F>
void in_strips_n(const std::vector<int>& ns, const F& f) {
  std::vector<int> strips(ns.size());
  for (std::size_t i = 0; i < ns.size(); ++i) strips[i] = std::max(1, std::min(ns[i] / 8, 4 * cv::getNumThreads()));
  parallel_for_parts(strips, [&](std::size_t i, int s) {
    f(i, int(int64_t(ns[i]) * s / strips[i]), int(int64_t(ns[i]) * (s + 1) / strips[i]));
  });
}

std::vector<int> rows_of(const std::vector<cv::Mat>& m) {
  std::vector<int> n;
  for (const cv::Mat& x : m) n.push_back(x.rows);
  return n;
}

std::vector<cv::Mat> to_float_n(const std::vector<cv::Mat>& grays) {
  std::vector<cv::Mat> out;
  for (const cv::Mat& g : grays) out.emplace_back(g.size(), CV_32FC(g.channels()));
  in_strips_n(rows_of(grays), [&](std::size_t i, int y0, int y1) {
    cv::Mat o = out[i].rowRange(y0, y1);
    grays[i].rowRange(y0, y1).convertTo(o, o.type());
  });
  return out;
}

// GaussianBlur (float images) into new matrices, by row strips (of all the images at once).
std::vector<cv::Mat> blurred_n(const std::vector<cv::Mat>& srcs, double sigma) {
  std::vector<cv::Mat> out;
  for (const cv::Mat& src : srcs) {
    CV_Assert(src.depth() == CV_32F);
    out.emplace_back(src.size(), src.type());
  }
  in_strips_n(rows_of(srcs), [&](std::size_t i, int y0, int y1) {
    cv::Mat d = out[i].rowRange(y0, y1);
    cv::GaussianBlur(srcs[i].rowRange(y0, y1), d, cv::Size(0, 0), sigma);
  });
  return out;
}

std::vector<cv::Mat> product_n(const std::vector<cv::Mat>& as, const std::vector<cv::Mat>& bs) {
  std::vector<cv::Mat> out;
  for (const cv::Mat& a : as) out.emplace_back(a.size(), a.type());
  in_strips_n(rows_of(as), [&](std::size_t i, int y0, int y1) {
    cv::Mat o = out[i].rowRange(y0, y1);
    cv::multiply(as[i].rowRange(y0, y1), bs[i].rowRange(y0, y1), o);
  });
  return out;
}

// The parts of `full` outside every rectangle of `holes` (which do not overlap each other),
// as rectangles: horizontal slabs between the holes' top and bottom edges, cut by the holes
// that span each slab.
std::vector<Rect> complement(int width, int height, const std::vector<Rect>& holes) {
  std::vector<int> ys = {0, height};
  for (const Rect& h : holes) {
    ys.push_back(std::clamp(h.y, 0, height));
    ys.push_back(std::clamp(h.y + h.height, 0, height));
  }
  std::sort(ys.begin(), ys.end());
  ys.erase(std::unique(ys.begin(), ys.end()), ys.end());
  std::vector<Rect> out;
  for (std::size_t k = 0; k + 1 < ys.size(); ++k) {
    const int y0 = ys[k], y1 = ys[k + 1];
    std::vector<std::pair<int, int>> cut;
    for (const Rect& h : holes)
      if (h.y <= y0 && h.y + h.height >= y1) cut.emplace_back(h.x, h.x + h.width);
    std::sort(cut.begin(), cut.end());
    int x = 0;
    for (const auto& c : cut) {
      if (c.first > x) out.push_back({x, y0, std::min(c.first, width) - x, y1 - y0});
      x = std::max(x, c.second);
    }
    if (x < width) out.push_back({x, y0, width - x, y1 - y0});
  }
  out.erase(std::remove_if(out.begin(), out.end(), [](const Rect& r) { return r.width <= 0 || r.height <= 0; }),
            out.end());
  return out;
}

// exp(-(|fwd(p) + bwd(p + fwd(p))| / tau)^2): 1 where the two directions agree. For several
// (fwd, bwd) pairs at once.
std::vector<cv::Mat> forward_backward_confidence_n(const std::vector<cv::Mat>& fwd, const std::vector<cv::Mat>& bwd,
                                                   float tau) {
  std::vector<cv::Mat> map, back(fwd.size()), conf;
  for (const cv::Mat& f : fwd) map.emplace_back(f.size(), CV_32FC2), conf.emplace_back(f.size(), CV_32F);
  parallel_for_parts(rows_of(fwd), [&](std::size_t i, int y) {
    const cv::Vec2f* pf = fwd[i].ptr<cv::Vec2f>(y);
    cv::Vec2f* pm = map[i].ptr<cv::Vec2f>(y);
    for (int x = 0; x < fwd[i].cols; ++x) pm[x] = cv::Vec2f(x + pf[x][0], y + pf[x][1]);
  });
  for (std::size_t i = 0; i < fwd.size(); ++i)
    cv::remap(bwd[i], back[i], map[i], cv::noArray(), cv::INTER_LINEAR, cv::BORDER_REPLICATE);
  const float inv = 1.f / (tau * tau);
  parallel_for_parts(rows_of(fwd), [&](std::size_t i, int y) {
    const cv::Vec2f* pf = fwd[i].ptr<cv::Vec2f>(y);
    const cv::Vec2f* pb = back[i].ptr<cv::Vec2f>(y);
    float* pc = conf[i].ptr<float>(y);
    for (int x = 0; x < fwd[i].cols; ++x) {
      const float ex = pf[x][0] + pb[x][0], ey = pf[x][1] + pb[x][1];
      pc[x] = std::exp(-(ex * ex + ey * ey) * inv);
    }
  });
  return conf;
}

float sample(const cv::Mat& img, float x, float y) {
  x = std::clamp(x, 0.f, float(img.cols - 1));
  y = std::clamp(y, 0.f, float(img.rows - 1));
  const int x0 = int(x), y0 = int(y);
  const int x1 = std::min(x0 + 1, img.cols - 1), y1 = std::min(y0 + 1, img.rows - 1);
  const float ax = x - float(x0), ay = y - float(y0);
  const float* r0 = img.ptr<float>(y0);
  const float* r1 = img.ptr<float>(y1);
  return (1.f - ay) * ((1.f - ax) * r0[x0] + ax * r0[x1]) + ay * ((1.f - ax) * r1[x0] + ax * r1[x1]);
}

// The matching-cost gate of the flow a->b (flow_gate_math.hpp): per pixel, how much the flow
// improves the match over the homography, blurred, mapped to 0..1. For several (a, b, flow) at once.
std::vector<cv::Mat> cost_gate_n(const std::vector<cv::Mat>& a, const std::vector<cv::Mat>& b,
                                 const std::vector<cv::Mat>& flow) {
  std::vector<cv::Mat> improvement;
  for (const cv::Mat& x : a) improvement.emplace_back(x.size(), CV_32F);
  parallel_for_parts(rows_of(a), [&](std::size_t i, int y) {
    const float* pa = a[i].ptr<float>(y);
    const float* pb = b[i].ptr<float>(y);
    const cv::Vec2f* pf = flow[i].ptr<cv::Vec2f>(y);
    float* pi = improvement[i].ptr<float>(y);
    for (int x = 0; x < a[i].cols; ++x)
      pi[x] = std::fabs(pa[x] - pb[x]) - std::fabs(pa[x] - sample(b[i], x + pf[x][0], y + pf[x][1]));
  });
  improvement = blurred_n(improvement, flow_gate::kGateSigma);
  parallel_for_parts(rows_of(a), [&](std::size_t i, int y) {
    float* pi = improvement[i].ptr<float>(y);
    for (int x = 0; x < a[i].cols; ++x) pi[x] = flow_gate::gate(pi[x]);
  });
  return improvement;
}

// Mean matching error of the views where both are valid, without the flow and with b sampled
// at p + flow(p) (flow_gate::match_error; gradients by central differences of samples).
void matching_errors(const cv::Mat& a, const cv::Mat& b, const cv::Mat& flow, const cv::Mat& both, double& homography,
                     double& with_flow) {
  // The per-pixel errors in parallel, then summed in raster order as before: the same sums
  // bit for bit, whatever the thread count.
  cv::Mat eh(a.size(), CV_32F), ef(a.size(), CV_32F);
  for_rows(a.rows, [&](int y) {
    const cv::Vec2f* pf = flow.ptr<cv::Vec2f>(y);
    const uint8_t* pm = both.ptr<uint8_t>(y);
    float* ph = eh.ptr<float>(y);
    float* pe = ef.ptr<float>(y);
    for (int x = 0; x < a.cols; ++x) {
      if (!pm[x]) continue;
      const float fx = float(x), fy = float(y);
      // At whole pixels a sample is the pixel itself (clamped into the image): read directly.
      const int xl = std::max(x - 1, 0), xr = std::min(x + 1, a.cols - 1);
      const float* a0 = a.ptr<float>(y);
      const float* b0 = b.ptr<float>(y);
      const float *au = a.ptr<float>(std::max(y - 1, 0)), *ad = a.ptr<float>(std::min(y + 1, a.rows - 1));
      const float *bu = b.ptr<float>(std::max(y - 1, 0)), *bd = b.ptr<float>(std::min(y + 1, b.rows - 1));
      const float av = a0[x], bv = b0[x];
      const float agx = 0.5f * (a0[xr] - a0[xl]);
      const float agy = 0.5f * (ad[x] - au[x]);
      const float bgx = 0.5f * (b0[xr] - b0[xl]);
      const float bgy = 0.5f * (bd[x] - bu[x]);
      const float qx = fx + pf[x][0], qy = fy + pf[x][1];
      const float wv = sample(b, qx, qy);
      const float wgx = 0.5f * (sample(b, qx + 1, qy) - sample(b, qx - 1, qy));
      const float wgy = 0.5f * (sample(b, qx, qy + 1) - sample(b, qx, qy - 1));
      ph[x] = flow_gate::match_error(av, bv, agx, agy, bgx, bgy);
      pe[x] = flow_gate::match_error(av, wv, agx, agy, wgx, wgy);
    }
  });
  double sh = 0, sf = 0;
  long n = 0;
  for (int y = 0; y < a.rows; ++y) {
    const uint8_t* pm = both.ptr<uint8_t>(y);
    const float* ph = eh.ptr<float>(y);
    const float* pe = ef.ptr<float>(y);
    for (int x = 0; x < a.cols; ++x) {
      if (!pm[x]) continue;
      sh += ph[x];
      sf += pe[x];
      ++n;
    }
  }
  homography = n ? sh / double(n) : 0.0;
  with_flow = n ? sf / double(n) : 0.0;
}

// Bands of rows one flow is split into (deterministic: from the size alone, never from the
// thread count, so the output does not depend on the machine).
int flow_bands(const cv::Size& work) {
  if (const char* e = std::getenv("STITCH_FLOW_BANDS")) return std::max(1, std::atoi(e));
  return std::max(1, work.height / 160);
}
// Rows (flow resolution) each band is widened by on both sides: the vertical room a band's
// flow has, and context for DIS's patches and its coarsest level.
constexpr int kBandMargin = 32;

class FlowWarperCpu final : public FlowWarper {
 public:
  FlowWarperCpu() : warper_(std::make_unique<WarperCpu>()) {}

  void prepare(const std::vector<ViewPlacement>& views, int out_width, int out_height) override {
    views_ = views;
    prefilter_sparse_views(views_);
    out_w_ = out_width;
    out_h_ = out_height;
    warper_->prepare(views_);
    build();
  }

  void set_settings(const FlowWarpSettings& s) override {
    const bool rebuild = flow_layout_changed(settings_, s);
    settings_ = sanitized(s);
    if (rebuild && !views_.empty()) build();
  }

  void reset() override {
    for (auto& p : pairs_) {
      p.history = false;
      p.decision = {};
    }
  }

  void warp(const std::vector<ImageView>& camera_frames, const std::vector<ImageView>& warped) override {
    if (camera_frames.size() != views_.size() || warped.size() != views_.size())
      throw std::invalid_argument("flow warp: view count differs from prepare()");
    check_frame_sizes(views_, camera_frames);
    for (std::size_t i = 0; i < camera_frames.size(); ++i) {
      if (camera_frames[i].empty() || views_[i].roi.empty()) continue;
      if (camera_frames[i].on_device || warped[i].on_device)
        throw std::invalid_argument("CPU flow warper got device memory");
      if (warped[i].width != views_[i].roi.width || warped[i].height != views_[i].roi.height)
        throw std::invalid_argument("flow warp: destination " + std::to_string(i) + " is not roi-sized");
    }
    // Sparsely sampled views read a reduced copy (prefilter_sparse_views).
    const std::vector<ImageView>& frames = reducer_.reduce(views_, camera_frames);
    // The homography warp of each view is written after the flows, and only where the flow
    // does not re-warp the view (displacement_fields()): the same pixels with less work.
    stats_.clear();
    if (!settings_.flow) {
      for (std::size_t i = 0; i < frames.size(); ++i)
        if (!frames[i].empty() && !views_[i].roi.empty()) warper_->warp(int(i), frames[i], warped[i]);
      return;
    }
    std::vector<Pair*> active;
    for (auto& p : pairs_) {
      if (frames[p.a].empty() || frames[p.b].empty()) {
        p.history = false;
        continue;
      }
      active.push_back(&p);
    }
    // STITCH_FLOW_PROFILE=1: each phase's wall time (and each flow task's) on stderr, to see
    // what bounds the stage on a many-core host.
    static const bool profile = std::getenv("STITCH_FLOW_PROFILE") != nullptr;
    using Clock = std::chrono::steady_clock;
    const auto ms = [](Clock::time_point a, Clock::time_point b) {
      return std::chrono::duration<double, std::milli>(b - a).count();
    };
    const Clock::time_point t0 = Clock::now();
    for (Pair* p : active) overlap_gray(*p, frames);
    const Clock::time_point t1 = Clock::now();
    // The dense flows (DIS runs serially inside) of every pair, both directions and every band
    // of rows run side by side; each has its own estimator, so they share no state.
    struct Task {
      Pair* p;
      int dir, band;
    };
    std::vector<Task> tasks;
    for (Pair* p : active)
      for (int dir = 0; dir < 2; ++dir)
        for (int k = 0; k < int(p->flow[dir].size()); ++k) tasks.push_back({p, dir, k});
    for (Pair* p : active)
      if (p->flow[0].size() > 1)
        for (int dir = 0; dir < 2; ++dir) p->next[dir].create(p->work, CV_32FC2);
    std::vector<double> task_ms(tasks.size());
    cv::parallel_for_(cv::Range(0, int(tasks.size())), [&](const cv::Range& r) {
      for (int t = r.start; t < r.end; ++t) {
        const Clock::time_point a = Clock::now();
        const Task& task = tasks[std::size_t(t)];
        flow_band(*task.p, task.dir, task.band);
        task_ms[std::size_t(t)] = ms(a, Clock::now());
      }
    }, double(tasks.size()));
    for (Pair* p : active)
      if (p->flow[0].size() > 1) {
        p->ab = p->next[0];
        p->ba = p->next[1];
        p->next[0] = p->next[1] = cv::Mat();
      }
    const Clock::time_point t2 = Clock::now();
    estimate_all(active);
    const Clock::time_point t3 = Clock::now();
    // Every view's homography-only parts, cut into bands of 32 rows, in one parallel loop (one
    // wait for the threads, not one per part); then the displaced bands.
    struct Part {
      int view;
      Rect rect;  // roi coordinates
    };
    std::vector<Part> parts;
    std::vector<std::vector<Rect>> moved(views_.size());
    std::vector<std::vector<cv::Mat>> fields(views_.size());
    for (std::size_t i = 0; i < views_.size(); ++i) {
      if (frames[i].empty() || views_[i].roi.empty()) continue;
      displacement_fields(int(i), frames, moved[i], fields[i]);
      for (const Rect& part : complement(views_[i].roi.width, views_[i].roi.height, moved[i]))
        for (int y = part.y; y < part.y + part.height; y += 32)
          parts.push_back({int(i), {part.x, y, part.width, std::min(32, part.y + part.height - y)}});
    }
    if (!parts.empty())
      cv::parallel_for_(cv::Range(0, int(parts.size())), [&](const cv::Range& r) {
        for (int k = r.start; k < r.end; ++k) {
          const Part& part = parts[std::size_t(k)];
          warper_->warp_part(part.view, frames[std::size_t(part.view)], warped[std::size_t(part.view)], part.rect);
        }
      }, double(parts.size()));
    for (std::size_t i = 0; i < views_.size(); ++i)
      for (std::size_t k = 0; k < moved[i].size(); ++k) {
        cv::Mat mx, my;
        camera_maps(views_[i], moved[i][k], fields[i][k], mx, my);
        cv::Mat out = as_mat(warped[i])(to_cv(moved[i][k]));
        cv::remap(as_mat(frames[i]), out, mx, my, cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar::all(0));
      }
    if (profile) {
      std::fprintf(stderr, "flow warp ms: overlaps %.1f, flows %.1f (%zu tasks, slowest %.1f), estimate %.1f, warp %.1f\n",
                   ms(t0, t1), ms(t1, t2), tasks.size(),
                   task_ms.empty() ? 0.0 : *std::max_element(task_ms.begin(), task_ms.end()), ms(t2, t3),
                   ms(t3, Clock::now()));
    }
  }

  const std::vector<FlowPairStats>& stats() const override { return stats_; }
  Backend backend() const override { return Backend::Cpu; }

 private:
  struct ViewSide {
    cv::Mat map_xy, map_frac;  // flow-resolution lookup into the camera (fixed point)
    cv::Mat valid;             // CV_8U: the camera covers the pixel
    cv::Mat theta;             // CV_32F, rect-sized: normalised blend weight
  };
  struct Pair {
    int a = 0, b = 0;
    Rect rect;               // output pixels
    cv::Size work;           // flow resolution
    ViewSide side[2];
    cv::Mat flow_ab, flow_ba;  // flow resolution, history for the next frame
    cv::Mat prev_gray[2];      // the views' overlap last frame, to tell static from moving
    cv::Mat full_ab, full_ba;  // output resolution, this frame
    bool history = false;
    flow_gate::Decision decision;  // whether the flow helps this overlap, and its gain
    // a->b and b->a, one estimator per band of rows (flow_bands()): all run at once.
    std::vector<std::shared_ptr<DenseFlow>> flow[2];  // (vector<unique_ptr> would make Pair look copyable)
    // This frame's scratch between the phases of warp().
    cv::Mat gray[2], ab, ba, prev_ab, prev_ba;
    cv::Mat next[2];  // the banded flows' output
    bool init = false;
  };

  void build() {
    // A recalibration moves the overlaps a little: the previous flow of a pair whose flow
    // rectangle keeps its size stays a good start, so a stream's history survives it.
    std::vector<Pair> old = std::move(pairs_);
    pairs_.clear();
    bands_.assign(views_.size(), {});
    std::vector<cv::Mat> weight(views_.size());
    cv::Mat sum(out_h_, out_w_, CV_32F, cv::Scalar(0));
    for (std::size_t i = 0; i < views_.size(); ++i) {
      weight[i] = position_weight_map(views_[i]);
      if (!weight[i].empty()) sum(to_cv(views_[i].roi)) += weight[i];
    }
    for (const FlowPairPlan& plan : plan_flow_pairs(views_, weight, settings_.margin, settings_.quality)) {
      const int a = plan.a, b = plan.b;
      const Rect rect = plan.rect;
      Pair p;
      p.a = a;
      p.b = b;
      p.rect = rect;
      p.work = cv::Size(plan.work_width, plan.work_height);
      for (auto& f : p.flow) {
        f.resize(std::size_t(flow_bands(p.work)));
        for (auto& e : f) e = DenseFlow::create(Backend::Cpu, settings_.algorithm, settings_.quality);
      }
      const cv::Mat s = sum(to_cv(rect));
      for (int k = 0; k < 2; ++k) {
        const int v = k == 0 ? a : b;
        const ViewPlacement& view = views_[v];
        const Rect part = shifted(rect, -view.roi.x, -view.roi.y);
        cv::Mat fx, fy;
        camera_maps(view, part, cv::Mat(), fx, fy);
        cv::resize(fx, fx, p.work, 0, 0, cv::INTER_LINEAR);
        cv::resize(fy, fy, p.work, 0, 0, cv::INTER_LINEAR);
        p.side[k].valid = (fx >= 0) & (fx <= view.camera_width - 1) & (fy >= 0) &
                          (fy <= view.camera_height - 1);
        cv::convertMaps(fx, fy, p.side[k].map_xy, p.side[k].map_frac, CV_16SC2);
        cv::Mat theta;
        cv::divide(weight[v](to_cv(part)), cv::max(s, 1e-12), theta);
        p.side[k].theta = theta;
      }
      for (Pair& o : old)
        if (o.a == a && o.b == b && o.history && o.work == p.work) {
          p.flow_ab = o.flow_ab;
          p.flow_ba = o.flow_ba;
          p.prev_gray[0] = o.prev_gray[0];
          p.prev_gray[1] = o.prev_gray[1];
          p.history = true;
          p.decision = o.decision;
        }
      bands_[a].push_back(rect);
      bands_[b].push_back(rect);
      pairs_.push_back(std::move(p));
    }
    // A view's rects that overlap (3 views meeting) are merged: displacements there add up.
    for (auto& list : bands_) {
      for (bool merged = true; merged;) {
        merged = false;
        for (std::size_t i = 0; i < list.size() && !merged; ++i)
          for (std::size_t j = i + 1; j < list.size() && !merged; ++j)
            if (!intersect(list[i], list[j]).empty()) {
              list[i] = bounding(list[i], list[j]);
              list.erase(list.begin() + long(j));
              merged = true;
            }
      }
    }
  }

  // The two views' overlap at flow resolution in grey, and the flows' starting points.
  void overlap_gray(Pair& p, const std::vector<ImageView>& frames) {
    cv::Mat* gray = p.gray;
    for (int k = 0; k < 2; ++k) {
      gray[k].release();  // last frame's buffer lives on as prev_gray: never write into it
      cv::Mat rgba;
      cv::remap(as_mat(frames[k == 0 ? p.a : p.b]), rgba, p.side[k].map_xy, p.side[k].map_frac,
                cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar::all(0));
      cv::cvtColor(rgba, gray[k], cv::COLOR_RGBA2GRAY);
    }
    // Where one view has no pixels, show it the other's: zero flow there, and no false
    // edges from the black outside a camera for the flow to latch onto.
    gray[1].copyTo(gray[0], ~p.side[0].valid);
    gray[0].copyTo(gray[1], ~p.side[1].valid);
    p.init = p.history;
    p.prev_ab = p.init ? p.flow_ab.clone() : cv::Mat();
    p.prev_ba = p.init ? p.flow_ba.clone() : cv::Mat();
    p.ab = p.init ? p.flow_ab : cv::Mat();
    p.ba = p.init ? p.flow_ba : cv::Mat();
  }

  // Band k of the flow in direction dir (0: a->b into p.ab, 1: b->a into p.ba). One band: the
  // whole overlap, in place, as before. Several: rows [y0, y1) are estimated on rows
  // [y0 - margin, y1 + margin) and written into p.next[dir]; each band starts from the rows of
  // the previous flow it covers (read only: the bands run at once).
  void flow_band(Pair& p, int dir, int k) {
    const cv::Mat& from = p.gray[dir];
    const cv::Mat& to = p.gray[1 - dir];
    cv::Mat& whole = dir == 0 ? p.ab : p.ba;
    DenseFlow& estimator = *p.flow[dir][std::size_t(k)];
    const int n = int(p.flow[dir].size());
    if (n == 1) {
      estimator.compute(from, to, whole, p.init);
      return;
    }
    const int rows = from.rows;
    const int y0 = int(int64_t(rows) * k / n), y1 = int(int64_t(rows) * (k + 1) / n);
    const int m = kBandMargin;
    const int s0 = std::max(0, y0 - m), s1 = std::min(rows, y1 + m);
    cv::Mat f = p.init ? whole.rowRange(s0, s1).clone() : cv::Mat();
    estimator.compute(from.rowRange(s0, s1), to.rowRange(s0, s1), f, p.init);
    f.rowRange(y0 - s0, y1 - s0).copyTo(p.next[dir].rowRange(y0, y1));
  }

  // After the flows: confidence, gating, refinement, stats and the output-resolution flows.
  // Every active pair at once: each step runs both directions of every pair in one parallel
  // loop (one wait for the threads, not one per pair and direction); item 2k is pair k's a->b,
  // 2k + 1 its b->a. Then each pair's stats and output-resolution flows.
  void estimate_all(const std::vector<Pair*>& pairs) {
    const double scale = flow_scale(settings_.quality);
    const float tau = float(settings_.consistency_px * scale);
    std::vector<cv::Mat> fwd, bwd, grays, prevs;
    for (Pair* p : pairs) {
      fwd.insert(fwd.end(), {p->ab, p->ba});
      bwd.insert(bwd.end(), {p->ba, p->ab});
      grays.insert(grays.end(), {p->gray[0], p->gray[1]});
      prevs.insert(prevs.end(), {p->prev_ab, p->prev_ba});
    }
    const std::vector<cv::Mat> conf = forward_backward_confidence_n(fwd, bwd, std::max(tau, 0.25f));
    // The flow counts only where it improves the match over the homography.
    const std::vector<cv::Mat> f = to_float_n(grays);  // 2k: view a's, 2k + 1: view b's
    std::vector<cv::Mat> trust = conf;
    if (settings_.fallback) {
      std::vector<cv::Mat> from, to;
      for (std::size_t k = 0; k < pairs.size(); ++k) {
        from.insert(from.end(), {f[2 * k], f[2 * k + 1]});
        to.insert(to.end(), {f[2 * k + 1], f[2 * k]});
      }
      trust = product_n(conf, cost_gate_n(from, to, fwd));
    }
    // The stillness of every pair with a history (its four images in the same loops): 1 where
    // neither view's overlap changed since the last frame, falling to 0 where either changed by a
    // few grey levels. Local means are compared, so sensor noise is not motion.
    std::vector<cv::Mat> still_of(pairs.size());
    {
      std::vector<cv::Mat> images;
      std::vector<std::size_t> with;
      for (std::size_t k = 0; k < pairs.size(); ++k) {
        const Pair& p = *pairs[k];
        if (!p.init || p.prev_gray[0].empty() || p.prev_gray[0].size() != p.gray[0].size()) continue;
        with.push_back(k);
        images.insert(images.end(), {p.gray[0], p.gray[1], p.prev_gray[0], p.prev_gray[1]});
      }
      const std::vector<cv::Mat> m = blurred_n(to_float_n(images), 2.0);
      std::vector<int> rows;
      for (const std::size_t k : with) {
        still_of[k].create(pairs[k]->gray[0].size(), CV_32F);
        rows.push_back(still_of[k].rows);
      }
      parallel_for_parts(rows, [&](std::size_t j, int y) {
        const float *a0 = m[4 * j].ptr<float>(y), *a1 = m[4 * j + 1].ptr<float>(y);
        const float *b0 = m[4 * j + 2].ptr<float>(y), *b1 = m[4 * j + 3].ptr<float>(y);
        float* ps = still_of[with[j]].ptr<float>(y);
        for (int x = 0; x < still_of[with[j]].cols; ++x) {
          const float change = std::max(std::fabs(a0[x] - b0[x]), std::fabs(a1[x] - b1[x]));
          const float c = std::max(0.f, change - 1.f) / 2.f;
          ps[x] = std::exp(-c * c);
        }
      });
    }
    std::vector<cv::Mat> stills;
    for (std::size_t k = 0; k < pairs.size(); ++k) stills.insert(stills.end(), {still_of[k], still_of[k]});
    const std::vector<cv::Mat> refined = refine_n(fwd, trust, prevs, stills);
    for (std::size_t k = 0; k < pairs.size(); ++k)
      finish_estimate(*pairs[k], conf[2 * k], f[2 * k], f[2 * k + 1], refined[2 * k], refined[2 * k + 1]);
  }

  // One pair's stats, gate decision and output-resolution flows, after estimate_all's loops.
  void finish_estimate(Pair& p, const cv::Mat& conf_ab, const cv::Mat& fa, const cv::Mat& fb, const cv::Mat& flow_ab,
                       const cv::Mat& flow_ba) {
    cv::Mat* gray = p.gray;
    const double scale = flow_scale(settings_.quality);
    cv::Mat both = p.side[0].valid & p.side[1].valid;
    FlowPairStats st;
    st.view_a = p.a;
    st.view_b = p.b;
    st.rect = p.rect;
    const int n_valid = cv::countNonZero(both);
    st.confident_fraction = n_valid ? cv::countNonZero((conf_ab > 0.5) & both) / double(n_valid) : 0.0;

    p.flow_ab = flow_ab;
    p.flow_ba = flow_ba;
    p.prev_gray[0] = gray[0];
    p.prev_gray[1] = gray[1];
    p.history = true;
    p.gray[0] = p.gray[1] = p.ab = p.ba = p.prev_ab = p.prev_ba = cv::Mat();

    cv::Mat mag(p.flow_ab.size(), CV_32F);
    in_strips(mag.rows, [&](int y0, int y1) {
      std::vector<cv::Mat> ch;
      cv::split(p.flow_ab.rowRange(y0, y1), ch);
      cv::Mat m = mag.rowRange(y0, y1);
      cv::magnitude(ch[0], ch[1], m);
    });
    st.mean_magnitude = n_valid ? cv::mean(mag, both)[0] / scale : 0.0;

    // This frame is warped with the gain decided last frame; what the flow did now decides
    // the next (flow_gate_math.hpp).
    const double gain = settings_.fallback ? p.decision.gain : 1.0;
    matching_errors(fa, fb, p.flow_ab, both, st.error_homography, st.error_flow);
    p.decision = flow_gate::update(p.decision, st.error_homography, st.error_flow);
    st.flow_on = p.decision.on;
    st.gain = p.decision.gain;
    stats_.push_back(st);

    const cv::Size full(p.rect.width, p.rect.height);
    cv::resize(p.flow_ab, p.full_ab, full, 0, 0, cv::INTER_LINEAR);
    cv::resize(p.flow_ba, p.full_ba, full, 0, 0, cv::INTER_LINEAR);
    in_strips(full.height, [&](int y0, int y1) {
      for (cv::Mat* f : {&p.full_ab, &p.full_ba}) {
        cv::Mat part = f->rowRange(y0, y1);
        part.convertTo(part, -1, gain / scale);
      }
    });
  }

  // Confidence-weighted flow (unreliable pixels fall back toward the homography), lightly
  // smoothed, then blended with the previous frame's where neither view changed: there the
  // scene is static and so is the right flow, so estimation jitter is averaged away; where
  // the content moved, the new flow is taken at once.
  // For several (flow, conf, prev, stillness) at once.
  std::vector<cv::Mat> refine_n(const std::vector<cv::Mat>& flow, const std::vector<cv::Mat>& conf,
                                const std::vector<cv::Mat>& prev, const std::vector<cv::Mat>& stillness) const {
    std::vector<cv::Mat> out;
    for (const cv::Mat& f : flow) out.emplace_back(f.size(), CV_32FC2);
    parallel_for_parts(rows_of(flow), [&](std::size_t i, int y) {
      const cv::Vec2f* pf = flow[i].ptr<cv::Vec2f>(y);
      const float* pc = conf[i].ptr<float>(y);
      cv::Vec2f* po = out[i].ptr<cv::Vec2f>(y);
      for (int x = 0; x < flow[i].cols; ++x) po[x] = pf[x] * pc[x];
    });
    out = blurred_n(out, 1.5);
    const float s = float(settings_.temporal_smoothing);
    if (s <= 0.f) return out;
    std::vector<int> rows;  // the flows with a previous one and a stillness to blend with
    for (std::size_t i = 0; i < out.size(); ++i)
      rows.push_back(prev[i].empty() || stillness[i].empty() ? 0 : out[i].rows);
    parallel_for_parts(rows, [&](std::size_t i, int y) {
      const cv::Vec2f* pp = prev[i].ptr<cv::Vec2f>(y);
      const float* ps = stillness[i].ptr<float>(y);
      cv::Vec2f* po = out[i].ptr<cv::Vec2f>(y);
      for (int x = 0; x < out[i].cols; ++x) {
        const float keep = s * ps[x];
        po[x] = keep * pp[x] + (1.f - keep) * po[x];
      }
    });
    return out;
  }

  // View v's bands (roi coordinates) that the flow moves, and their displacement fields; the
  // rest of the view is the homography's (warp() warps both).
  void displacement_fields(int v, const std::vector<ImageView>& frames, std::vector<Rect>& moved,
                           std::vector<cv::Mat>& fields) {
    const ViewPlacement& view = views_[v];
    for (const Rect& band : bands_[v]) {
      cv::Mat d(band.height, band.width, CV_32FC2);
      in_strips(d.rows, [&](int y0, int y1) { d.rowRange(y0, y1).setTo(cv::Scalar::all(0)); });
      bool any = false;
      for (const Pair& p : pairs_) {
        if ((p.a != v && p.b != v) || !p.history || frames[p.a].empty() || frames[p.b].empty()) continue;
        if (intersect(p.rect, band).empty()) continue;
        // View a samples at p + θ_b flow_{b→a}; view b at p + θ_a flow_{a→b}.
        const bool is_a = p.a == v;
        const cv::Mat& flow = is_a ? p.full_ba : p.full_ab;
        const cv::Mat& theta = p.side[is_a ? 1 : 0].theta;
        cv::Mat part = d(to_cv(shifted(p.rect, -band.x, -band.y)));
        for_rows(part.rows, [&](int y) {
          const cv::Vec2f* pf = flow.ptr<cv::Vec2f>(y);
          const float* pt = theta.ptr<float>(y);
          cv::Vec2f* pd = part.ptr<cv::Vec2f>(y);
          for (int x = 0; x < part.cols; ++x) pd[x] += pt[x] * pf[x];
        });
        any = true;
      }
      if (!any) continue;
      std::vector<float> row_max(std::size_t(d.rows), 0.f);
      for_rows(d.rows, [&](int y) {
        const float* pd = d.ptr<float>(y);
        float m = 0.f;
        for (int x = 0; x < 2 * d.cols; ++x) m = std::max(m, std::fabs(pd[x]));
        row_max[std::size_t(y)] = m;
      });
      if (*std::max_element(row_max.begin(), row_max.end()) < kNegligiblePx) continue;
      moved.push_back(shifted(band, -view.roi.x, -view.roi.y));
      fields.push_back(d);
    }
  }

  std::unique_ptr<WarperCpu> warper_;
  FlowWarpSettings settings_;
  std::vector<ViewPlacement> views_;
  FrameReducer reducer_;
  int out_w_ = 0, out_h_ = 0;
  std::vector<Pair> pairs_;
  std::vector<std::vector<Rect>> bands_;  // per view: output rects its flow moves
  std::vector<FlowPairStats> stats_;
};

}  // namespace

std::unique_ptr<FlowWarper> FlowWarper::create(Backend backend) {
  switch (resolve_backend(backend, /*stage_has_cuda=*/true)) {
    case Backend::Cpu: return std::make_unique<FlowWarperCpu>();
#ifdef STITCH_HAVE_CUDA
    case Backend::Cuda: return make_flow_warper_cuda();
#endif
    default: break;
  }
  throw std::runtime_error("no flow warper for this backend");
}

}  // namespace stitch
