#include <cstring>
#include <algorithm>
#include <map>
#include <opencv2/core.hpp>
#include <stdexcept>

#include "stitch/blend/blender_cpu.hpp"
#include "stitch/blend/multiband.hpp"
#include "stitch/blend/pyramid_math.hpp"

#ifdef STITCH_HAVE_CUDA
#include "stitch/cuda/stages_cuda.hpp"
#endif

namespace stitch {

MultibandLayout plan_multiband(const std::vector<ViewPlacement>& views, int width, int height, int bands) {
  if (width <= 0 || height <= 0) throw std::invalid_argument("multiband: empty output");
  if (bands < 0) throw std::invalid_argument("multiband: negative band count");
  MultibandLayout l;
  l.bands = bands;
  while (l.bands > 0 && (std::min(width, height) >> l.bands) < 2) --l.bands;
  const int unit = 1 << l.bands;
  l.width = width;
  l.height = height;
  l.padded_width = (width + unit - 1) / unit * unit;
  l.padded_height = (height + unit - 1) / unit * unit;
  // Widened like OpenCV's MultiBandBlender (3 · 2^bands), so that a view's coarse mask can
  // spread past its rectangle.
  const int gap = 3 * unit;
  l.fill_width = l.fill_height = unit;
  auto add_piece = [&](int view, const Rect& part) {
    l.fill_width = std::max(l.fill_width, padded_to_bands(part.width, l.bands));
    l.fill_height = std::max(l.fill_height, padded_to_bands(part.height, l.bands));
    const int x0 = std::max(0, (part.x - gap) / unit * unit);
    const int y0 = std::max(0, (part.y - gap) / unit * unit);
    const int x1 = std::min(l.padded_width, (part.x + part.width + gap + unit - 1) / unit * unit);
    const int y1 = std::min(l.padded_height, (part.y + part.height + gap + unit - 1) / unit * unit);
    const Rect rect{x0, y0, x1 - x0, y1 - y0};
    l.max_rect_width = std::max(l.max_rect_width, rect.width);
    l.max_rect_height = std::max(l.max_rect_height, rect.height);
    l.pieces.push_back({view, part, rect});
  };
  for (std::size_t i = 0; i < views.size(); ++i) {
    const ViewPlacement& v = views[i];
    if (v.roi.empty()) continue;
    const Rect& r = v.roi;
    if (v.wrap_width == width && r.x == 0 && r.width == width) {
      // Across the wrap: the columns from span_x0 to the right edge, and from the left edge to
      // span_x1 - width, when their pyramids (widened by the gap) stay apart.
      const int right_x = std::max(0, int(std::floor(v.span_x0)));
      const int left_end = std::min(width, int(std::ceil(v.span_x1)) - width + 1);
      if (left_end > 0 && right_x < width && left_end + 2 * gap + 2 * unit < right_x) {
        add_piece(int(i), Rect{0, r.y, left_end, r.height});
        add_piece(int(i), Rect{right_x, r.y, width - right_x, r.height});
        continue;
      }
    }
    add_piece(int(i), r);
  }
  return l;
}

std::vector<uint8_t> nearest_view_labels(const std::vector<ViewPlacement>& views, int width, int height,
                                         uint64_t present_mask) {
  if (views.size() > 64 || views.size() >= kNoView) throw std::invalid_argument("too many views");
  std::vector<uint8_t> labels(std::size_t(width) * height, kNoView);
  std::vector<float> best(labels.size(), 0.f);
  for (std::size_t i = 0; i < views.size(); ++i) {
    if (!(present_mask >> i & 1) || views[i].roi.empty()) continue;
    const Rect& r = views[i].roi;
    const cv::Mat w = position_weight_map(views[i]);
    for (int y = 0; y < r.height; ++y) {
      const float* pw = w.ptr<float>(y);
      const std::size_t row = std::size_t(r.y + y) * width + r.x;
      for (int x = 0; x < r.width; ++x)
        if (pw[x] > best[row + x]) {
          best[row + x] = pw[x];
          labels[row + x] = uint8_t(i);
        }
    }
  }
  return labels;
}

namespace {

// Rounds like the CUDA kernels' to_u8 (half up), so both backends agree.
inline uint8_t to_u8(float v) { return uint8_t(std::min(std::max(v + 0.5f, 0.f), 255.f)); }

using Level = cv::Mat;  // CV_32FC4: rgb, and the mask's weight in the fourth channel

// The top-left rows x cols of a buffer allocated once (no allocation per frame).
Level part(const Level& full, int rows, int cols) {
  CV_Assert(rows <= full.rows && cols <= full.cols);
  return full(cv::Rect(0, 0, cols, rows));
}

// Separable pyrDown (w x h -> w/2 x h/2) and pyrUp (-> 2w x 2h) into dst (sized by the caller),
// pyramid_math's definitions; `scratch` holds the pass between the two.
// d = sum of taps w[k] · s[k] over 4 channels (the taps in the order pyramid_math sums them).
inline void taps4(float* d, const float* const* s, const float* w, int n) {
  float a0 = 0, a1 = 0, a2 = 0, a3 = 0;
  for (int k = 0; k < n; ++k) a0 += s[k][0] * w[k], a1 += s[k][1] * w[k], a2 += s[k][2] * w[k], a3 += s[k][3] * w[k];
  d[0] = a0, d[1] = a1, d[2] = a2, d[3] = a3;
}

void down(const Level& src, const Level& scratch, Level dst) {
  Level tmp = part(scratch, src.rows, dst.cols);
  const float w5[5] = {pyramid::binomial_tap(-2), pyramid::binomial_tap(-1), pyramid::binomial_tap(0),
                       pyramid::binomial_tap(1), pyramid::binomial_tap(2)};
  cv::parallel_for_(cv::Range(0, src.rows), [&](const cv::Range& r) {
    for (int y = r.start; y < r.end; ++y) {
      const float* s = src.ptr<float>(y);
      float* d = tmp.ptr<float>(y);
      const float* t[5];
      for (int x = 0; x < tmp.cols; ++x) {
        const bool inside = 2 * x - 2 >= 0 && 2 * x + 2 < src.cols;  // no mirrored tap
        for (int i = -2; i <= 2; ++i) t[i + 2] = s + 4 * (inside ? 2 * x + i : pyramid::down_source(x, i, src.cols));
        taps4(d + 4 * x, t, w5, 5);
      }
    }
  });
  cv::parallel_for_(cv::Range(0, dst.rows), [&](const cv::Range& r) {
    for (int y = r.start; y < r.end; ++y) {
      const float* rows[5];
      for (int i = -2; i <= 2; ++i) rows[i + 2] = tmp.ptr<float>(pyramid::down_source(y, i, tmp.rows));
      float* d = dst.ptr<float>(y);
      for (int x = 0; x < 4 * dst.cols; ++x) {
        float a = 0;
        for (int i = 0; i < 5; ++i) a += rows[i][x] * w5[i];
        d[x] = a;
      }
    }
  });
}

void up(const Level& src, const Level& scratch, Level dst) {
  Level tmp = part(scratch, src.rows, dst.cols);
  cv::parallel_for_(cv::Range(0, src.rows), [&](const cv::Range& r) {
    for (int y = r.start; y < r.end; ++y) {
      const float* s = src.ptr<float>(y);
      float* d = tmp.ptr<float>(y);
      const float* t[5];
      float w[5];
      for (int x = 0; x < tmp.cols; ++x) {
        int n = 0;  // the taps that fall on source pixels (2 or 3), in pyramid_math's order
        for (int i = -2; i <= 2; ++i) {
          const int k = pyramid::up_source(x, i, tmp.cols, w[n]);
          if (k >= 0) t[n++] = s + 4 * k;
        }
        taps4(d + 4 * x, t, w, n);
      }
    }
  });
  cv::parallel_for_(cv::Range(0, dst.rows), [&](const cv::Range& r) {
    for (int y = r.start; y < r.end; ++y) {
      const float* t[5];
      float w[5];
      int n = 0;
      for (int i = -2; i <= 2; ++i) {
        const int k = pyramid::up_source(y, i, dst.rows, w[n]);
        if (k >= 0) t[n++] = tmp.ptr<float>(k);
      }
      float* d = dst.ptr<float>(y);
      for (int x = 0; x < 4 * dst.cols; ++x) {
        float a = 0;
        for (int k = 0; k < n; ++k) a += t[k][x] * w[k];
        d[x] = a;
      }
    }
  });
}

// Pull-push hole filling of one view (roi-sized, alpha = coverage) over `pull` and `fill`
// (levels 0..L, each at least the roi padded to 2^L): pull = the colours premultiplied by
// coverage, pyramid down; fill = pull's colours normalised at the coarsest level, then, level
// by level, the view's own colours where it has content and the coarser fill where it has
// none. fill[0]'s roi-sized corner is the view with its holes filled from its own content.
void fill_holes(const ImageView& v, int L, std::vector<Level>& pull, std::vector<Level>& fill, const Level& upper_buf,
                const Level& scratch) {
  const int fw = padded_to_bands(v.width, L), fh = padded_to_bands(v.height, L);
  std::vector<Level> p(L + 1), f(L + 1);
  for (int k = 0; k <= L; ++k) {
    p[k] = part(pull[k], fh >> k, fw >> k);
    f[k] = part(fill[k], fh >> k, fw >> k);
  }
  cv::parallel_for_(cv::Range(0, fh), [&](const cv::Range& r) {
    for (int y = r.start; y < r.end; ++y) {
      float* d = p[0].ptr<float>(y);
      for (int x = 0; x < fw; ++x) {
        if (y >= v.height || x >= v.width) {
          d[4 * x] = d[4 * x + 1] = d[4 * x + 2] = d[4 * x + 3] = 0.f;
          continue;
        }
        const uint8_t* s = v.row(y) + 4 * x;
        const float a = s[3] * (1.f / 255.f);
        d[4 * x] = s[0] * a, d[4 * x + 1] = s[1] * a, d[4 * x + 2] = s[2] * a, d[4 * x + 3] = a;
      }
    }
  });
  for (int k = 1; k <= L; ++k) down(p[k - 1], scratch, p[k]);
  auto push = [&](int k, const Level* upper) {  // f[k] = p.rgb + (1 - p.a) · upper (or p.rgb / p.a)
    cv::parallel_for_(cv::Range(0, f[k].rows), [&](const cv::Range& r) {
      for (int y = r.start; y < r.end; ++y) {
        const float* pp = p[k].ptr<float>(y);
        const float* pu = upper ? upper->ptr<float>(y) : nullptr;
        float* pf = f[k].ptr<float>(y);
        for (int x = 0; x < f[k].cols; ++x) {
          const float a = pp[4 * x + 3];
          for (int c = 0; c < 3; ++c)
            pf[4 * x + c] = pu ? pp[4 * x + c] + (1.f - a) * pu[4 * x + c] : pp[4 * x + c] / (a + 1e-5f);
          pf[4 * x + 3] = a;
        }
      }
    });
  };
  push(L, nullptr);
  for (int k = L - 1; k >= 0; --k) {
    const Level upper = part(upper_buf, f[k].rows, f[k].cols);
    up(f[k + 1], scratch, upper);
    push(k, &upper);
  }
}

class MultibandBlenderCpu final : public MultibandBlender {
 public:
  explicit MultibandBlenderCpu(int bands) : bands_(bands) {}

  void prepare(const std::vector<ViewPlacement>& views, int out_width, int out_height) override {
    if (views.size() > 64) throw std::invalid_argument("at most 64 views");
    views_ = views;
    layout_ = plan_multiband(views, out_width, out_height, bands_);
    nearest_.clear();
    const int max_w = layout_.max_rect_width, max_h = layout_.max_rect_height;
    acc_.assign(layout_.bands + 1, Level());
    gauss_.assign(layout_.bands + 1, Level());
    for (int k = 0; k <= layout_.bands; ++k) {
      acc_[k].create(layout_.padded_height >> k, layout_.padded_width >> k, CV_32FC4);
      gauss_[k].create(max_h >> k, max_w >> k, CV_32FC4);
    }
    upper_.create(layout_.padded_height, layout_.padded_width, CV_32FC4);
    scratch_.create(layout_.padded_height, layout_.padded_width, CV_32FC4);
    const int fill_w = layout_.fill_width, fill_h = layout_.fill_height;
    pull_.assign(layout_.bands + 1, Level());
    filled_.assign(layout_.bands + 1, Level());
    for (int k = 0; k <= layout_.bands; ++k) {
      pull_[k].create(fill_h >> k, fill_w >> k, CV_32FC4);
      filled_[k].create(fill_h >> k, fill_w >> k, CV_32FC4);
    }
    upper_.create(std::max(upper_.rows, fill_h), std::max(upper_.cols, fill_w), CV_32FC4);
    scratch_.create(std::max(scratch_.rows, fill_h), std::max(scratch_.cols, fill_w), CV_32FC4);
  }

  void set_labels(const uint8_t* labels, bool on_device) override {
    if (on_device) throw std::invalid_argument("the CPU multiband blender takes labels in host memory");
    if (labels) custom_.assign(labels, labels + std::size_t(layout_.width) * layout_.height);
    else custom_.clear();
  }
  const MultibandLayout& layout() const override { return layout_; }
  Backend backend() const override { return Backend::Cpu; }

  void fuse(const std::vector<ImageView>& warped, const ImageView& out) override {
    if (warped.size() != views_.size()) throw std::invalid_argument("view count differs from prepare()");
    if (out.width != layout_.width || out.height != layout_.height)
      throw std::invalid_argument("output size differs from prepare()");
    if (out.on_device) throw std::invalid_argument("CPU blender got device memory");
    uint64_t mask = 0;
    for (std::size_t i = 0; i < warped.size(); ++i)
      if (!warped[i].empty() && !views_[i].roi.empty()) mask |= uint64_t(1) << i;
    const std::vector<uint8_t>& labels = labels_for(mask);
    const int L = layout_.bands;
    std::vector<Level>& acc = acc_;
    for (int k = 0; k <= L; ++k) zero(acc[k]);
    std::vector<Level> g(L + 1);
    for (const MultibandPiece& piece : layout_.pieces) {
      const int i = piece.view;
      if (!(mask >> i & 1)) continue;
      const Rect& pr = piece.rect;
      for (int k = 0; k <= L; ++k) g[k] = part(gauss_[k], pr.height >> k, pr.width >> k);
      fill_holes(piece_pixels(warped[i], views_[i].roi, piece), L, pull_, filled_, upper_, scratch_);
      load_view(piece, filled_[0], labels, g[0]);
      for (int k = 1; k <= L; ++k) down(g[k - 1], scratch_, g[k]);
      for (int k = 0; k <= L; ++k) {
        const Level upper = k < L ? part(upper_, g[k].rows, g[k].cols) : Level();
        if (k < L) up(g[k + 1], scratch_, upper);
        Level a = acc[k](cv::Rect(pr.x >> k, pr.y >> k, pr.width >> k, pr.height >> k));
        cv::parallel_for_(cv::Range(0, a.rows), [&](const cv::Range& r) {
          for (int y = r.start; y < r.end; ++y) {
            const cv::Vec4f* pg = g[k].ptr<cv::Vec4f>(y);
            const cv::Vec4f* pu = k < L ? upper.ptr<cv::Vec4f>(y) : nullptr;
            cv::Vec4f* pa = a.ptr<cv::Vec4f>(y);
            for (int x = 0; x < a.cols; ++x) {
              const float w = pg[x][3];
              for (int c = 0; c < 3; ++c) pa[x][c] += (pg[x][c] - (pu ? pu[x][c] : 0.f)) * w;
              pa[x][3] += w;
            }
          }
        });
      }
    }
    // Normalise every band by its summed weight, then collapse from the coarsest level.
    for (int k = 0; k <= L; ++k) normalise(acc[k]);
    // Collapse in place: acc[k] += up(acc[k + 1]) (the fourth channel is meaningless from here on).
    for (int k = L - 1; k >= 0; --k) {
      const Level upper = part(upper_, acc[k].rows, acc[k].cols);
      up(acc[k + 1], scratch_, upper);
      add_rows(acc[k], upper);
    }
    const Level& img = acc[0];
    cv::parallel_for_(cv::Range(0, out.height), [&](const cv::Range& r) {
      for (int y = r.start; y < r.end; ++y) {
        const cv::Vec4f* p = img.ptr<cv::Vec4f>(y);
        const uint8_t* lab = labels.data() + std::size_t(y) * out.width;
        uint8_t* o = out.row(y);
        for (int x = 0; x < out.width; ++x) {
          for (int c = 0; c < 3; ++c) o[4 * x + c] = lab[x] == kNoView ? 0 : to_u8(p[x][c]);
          o[4 * x + 3] = 255;
        }
      }
    });
  }

 private:
  // Level-wide passes in whole rows on every core (cv::Mat's setTo and += run on one).
  static void zero(Level& a) {
    cv::parallel_for_(cv::Range(0, a.rows), [&](const cv::Range& r) {
      for (int y = r.start; y < r.end; ++y) std::memset(a.ptr<float>(y), 0, std::size_t(a.cols) * 4 * sizeof(float));
    });
  }
  static void add_rows(Level& a, const Level& b) {
    cv::parallel_for_(cv::Range(0, a.rows), [&](const cv::Range& r) {
      for (int y = r.start; y < r.end; ++y) {
        float* pa = a.ptr<float>(y);
        const float* pb = b.ptr<float>(y);
        for (int x = 0; x < a.cols * 4; ++x) pa[x] += pb[x];
      }
    });
  }
  static void normalise(Level& a) {
    cv::parallel_for_(cv::Range(0, a.rows), [&](const cv::Range& r) {
      for (int y = r.start; y < r.end; ++y) {
        cv::Vec4f* p = a.ptr<cv::Vec4f>(y);
        for (int x = 0; x < a.cols; ++x) {
          const float inv = 1.f / (p[x][3] + 1e-5f);
          p[x] = cv::Vec4f(p[x][0] * inv, p[x][1] * inv, p[x][2] * inv, 0.f);
        }
      }
    });
  }

  // Level 0 of view i over its padded rectangle: its hole-filled pixels (`filled`, roi at the
  // top left; mirrored outside the roi) and its mask (1 where the labels give it the pixel).
  void load_view(const MultibandPiece& piece, const Level& filled, const std::vector<uint8_t>& labels, Level g) const {
    const int i = piece.view;
    const Rect& pr = piece.rect;
    const Rect& roi = piece.part;
    cv::parallel_for_(cv::Range(0, pr.height), [&](const cv::Range& r) {
      for (int y = r.start; y < r.end; ++y) {
        const int cy = pr.y + y;
        const float* src = filled.ptr<float>(pyramid::reflect(cy - roi.y, roi.height));
        const uint8_t* lab = cy < layout_.height ? labels.data() + std::size_t(cy) * layout_.width : nullptr;
        cv::Vec4f* d = g.ptr<cv::Vec4f>(y);
        for (int x = 0; x < pr.width; ++x) {
          const int cx = pr.x + x;
          const float* p = src + 4 * pyramid::reflect(cx - roi.x, roi.width);
          const bool mine = lab && cx < layout_.width && lab[cx] == i;
          d[x] = cv::Vec4f(p[0], p[1], p[2], mine ? 1.f : 0.f);
        }
      }
    });
  }

  const std::vector<uint8_t>& labels_for(uint64_t mask) {
    auto it = nearest_.find(mask);
    if (it == nearest_.end()) {
      if (nearest_.size() > 16) nearest_.clear();
      it = nearest_.emplace(mask, nearest_view_labels(views_, layout_.width, layout_.height, mask)).first;
    }
    if (custom_.empty()) return it->second;
    merged_ = custom_;
    for (std::size_t p = 0; p < merged_.size(); ++p)
      if (merged_[p] == kNoView || !(mask >> merged_[p] & 1)) merged_[p] = it->second[p];
    return merged_;
  }

  int bands_;
  std::vector<ViewPlacement> views_;
  MultibandLayout layout_;
  std::map<uint64_t, std::vector<uint8_t>> nearest_;
  std::vector<uint8_t> custom_, merged_;
  // Allocated once per geometry: the canvas pyramid, one view's Gaussian pyramid (at the largest
  // view's size), the upsampled level and the pass between the separable filters.
  std::vector<Level> acc_, gauss_, pull_, filled_;  // pull_, filled_: the hole filling (fill_holes)
  Level upper_, scratch_;
};

}  // namespace

cv::Mat multiband_filled_view(const ImageView& view, int bands) {
  const int fw = padded_to_bands(view.width, bands), fh = padded_to_bands(view.height, bands);
  std::vector<Level> pull(bands + 1), fill(bands + 1);
  for (int k = 0; k <= bands; ++k) {
    pull[k].create(fh >> k, fw >> k, CV_32FC4);
    fill[k].create(fh >> k, fw >> k, CV_32FC4);
  }
  Level upper(fh, fw, CV_32FC4), scratch(fh, fw, CV_32FC4);
  fill_holes(view, bands, pull, fill, upper, scratch);
  return fill[0](cv::Rect(0, 0, view.width, view.height)).clone();
}

std::unique_ptr<MultibandBlender> MultibandBlender::create(Backend backend, int bands) {
  switch (resolve_backend(backend, /*stage_has_cuda=*/true)) {
#ifdef STITCH_HAVE_CUDA
    case Backend::Cuda: return make_multiband_blender_cuda(bands);
#endif
    case Backend::Cpu: return std::make_unique<MultibandBlenderCpu>(bands);
    default: break;
  }
  throw std::runtime_error("no multiband blender for this backend");
}

std::unique_ptr<Blender> make_blender(Backend backend, BlendMode mode, int bands) {
  if (mode == BlendMode::Multiband) return MultibandBlender::create(backend, bands);
  return Blender::create(backend);
}

}  // namespace stitch
