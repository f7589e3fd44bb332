// Frame conversion (stitch/convert): the CPU implementation against known colour values, and the
// CUDA implementation against the CPU one on a real photo (PSNR >= 45 dB; both follow the same
// integer math, so they should agree exactly). The CUDA tests need a device: without one (or
// in a build without the toolkit) they skip and say why.
#include <gtest/gtest.h>

#include <cmath>
#include <opencv2/imgproc.hpp>

#include "image_compare.hpp"
#include "cuda_test.hpp"
#include "ppm.hpp"
#include "stitch/backend.hpp"
#include "stitch/convert/convert.hpp"
#include "stitch/cv_interop.hpp"

#ifdef STITCH_HAVE_CUDA
#include <cuda_runtime_api.h>
#endif

using namespace stitch;

namespace {

#define REQUIRE_CUDA() REQUIRE_CUDA_FOR("the CUDA frame converter")

const YuvColorimetry kBt601{0.299, 0.114, false, false, false};
const YuvColorimetry kBt709{0.2126, 0.0722, false, true, false};  // H.264's chroma siting

// A 4:2:0 frame in system memory: Y plane, then Cb and Cr (I420) or interleaved CbCr (NV12).
struct Yuv420 {
  FrameFormat format;
  int width, height;
  cv::Mat y, cb, cr;  // planar, (w+1)/2 x (h+1)/2 chroma
  cv::Mat uv;         // NV12's interleaved plane
  FrameView view(const YuvColorimetry& c) const {
    FrameView v;
    v.format = format;
    v.width = width;
    v.height = height;
    v.colorimetry = c;
    v.planes[0] = y.data;
    v.pitches[0] = y.step;
    if (format == FrameFormat::NV12) {
      v.planes[1] = uv.data;
      v.pitches[1] = uv.step;
    } else {
      v.planes[1] = cb.data;
      v.pitches[1] = cb.step;
      v.planes[2] = cr.data;
      v.pitches[2] = cr.step;
    }
    return v;
  }
};

// Y'CbCr of an R'G'B' colour (the inverse of what the converter computes), unrounded.
std::array<double, 3> to_ycbcr(const cv::Vec4b& rgb, const YuvColorimetry& c) {
  const double r = rgb[0] / 255.0, g = rgb[1] / 255.0, b = rgb[2] / 255.0;
  const double y = c.kr * r + (1 - c.kr - c.kb) * g + c.kb * b;
  const double cb = (b - y) / (2 * (1 - c.kb)), cr = (r - y) / (2 * (1 - c.kr));
  if (c.full_range) return {255 * y, 128 + 255 * cb, 128 + 255 * cr};
  return {16 + 219 * y, 128 + 224 * cb, 128 + 224 * cr};
}

uint8_t u8(double v) { return cv::saturate_cast<uint8_t>(std::lround(v)); }

// `rgba` to 4:2:0 with chroma averaged over each 2x2 block (edges replicated).
Yuv420 to_yuv420(const cv::Mat& rgba, FrameFormat format, const YuvColorimetry& c) {
  Yuv420 f{format, rgba.cols, rgba.rows, {}, {}, {}, {}};
  const int cw = (f.width + 1) / 2, ch = (f.height + 1) / 2;
  f.y.create(f.height, f.width, CV_8U);
  f.cb.create(ch, cw, CV_8U);
  f.cr.create(ch, cw, CV_8U);
  for (int y = 0; y < f.height; ++y)
    for (int x = 0; x < f.width; ++x) f.y.at<uint8_t>(y, x) = u8(to_ycbcr(rgba.at<cv::Vec4b>(y, x), c)[0]);
  for (int j = 0; j < ch; ++j)
    for (int i = 0; i < cw; ++i) {
      double cb = 0, cr = 0;
      for (int dy = 0; dy < 2; ++dy)
        for (int dx = 0; dx < 2; ++dx) {
          const auto v = to_ycbcr(rgba.at<cv::Vec4b>(std::min(2 * j + dy, f.height - 1), std::min(2 * i + dx, f.width - 1)), c);
          cb += v[1] / 4;
          cr += v[2] / 4;
        }
      f.cb.at<uint8_t>(j, i) = u8(cb);
      f.cr.at<uint8_t>(j, i) = u8(cr);
    }
  if (format == FrameFormat::NV12) {
    f.uv.create(ch, cw * 2, CV_8U);
    for (int j = 0; j < ch; ++j)
      for (int i = 0; i < cw; ++i) {
        f.uv.at<uint8_t>(j, 2 * i) = f.cb.at<uint8_t>(j, i);
        f.uv.at<uint8_t>(j, 2 * i + 1) = f.cr.at<uint8_t>(j, i);
      }
  }
  return f;
}

cv::Mat convert_cpu(const FrameView& in) {
  cv::Mat out(in.height, in.width, CV_8UC4, cv::Scalar::all(77));
  auto conv = FrameConverter::create(Backend::Cpu);
  conv->convert(in, as_view(out));
  conv->finish();
  return out;
}

}  // namespace

// Uniform frames of known colours come back within a level (limited and full range, BT.601 and
// BT.709), and the range ends are exact.
TEST(Convert, KnownColoursRoundTrip) {
  const cv::Vec4b colours[] = {{0, 0, 0, 255},     {255, 255, 255, 255}, {255, 0, 0, 255}, {0, 255, 0, 255},
                               {0, 0, 255, 255},   {128, 128, 128, 255}, {200, 120, 40, 255},
                               {30, 90, 210, 255}, {250, 250, 10, 255}};
  for (YuvColorimetry c : {kBt601, kBt709}) {
    for (bool full : {false, true}) {
      c.full_range = full;
      for (const cv::Vec4b& colour : colours) {
        const Yuv420 f = to_yuv420(cv::Mat(6, 8, CV_8UC4, colour), FrameFormat::I420, c);
        const cv::Mat out = convert_cpu(f.view(c));
        const cv::Vec4b got = out.at<cv::Vec4b>(3, 5);
        for (int ch = 0; ch < 3; ++ch)
          EXPECT_NEAR(int(got[ch]), int(colour[ch]), 2)
              << "kr " << c.kr << (full ? " full" : " limited") << " colour " << colour << " got " << got;
        EXPECT_EQ(got[3], 255);
        EXPECT_EQ(cv::norm(out, cv::Mat(out.size(), CV_8UC4, cv::Scalar(got)), cv::NORM_INF), 0.0)
            << "a uniform frame gives a uniform image";
      }
    }
  }
  // Limited-range black and white are exact; values beyond the range clamp.
  Yuv420 f = to_yuv420(cv::Mat(4, 4, CV_8UC4, cv::Scalar(0, 0, 0, 255)), FrameFormat::I420, kBt709);
  EXPECT_EQ(convert_cpu(f.view(kBt709)).at<cv::Vec4b>(1, 1), cv::Vec4b(0, 0, 0, 255));
  f.y.setTo(235);
  EXPECT_EQ(convert_cpu(f.view(kBt709)).at<cv::Vec4b>(1, 1), cv::Vec4b(255, 255, 255, 255));
  f.y.setTo(255);
  f.cr.setTo(255);
  EXPECT_EQ(convert_cpu(f.view(kBt709)).at<cv::Vec4b>(1, 1)[0], 255);
  f.y.setTo(0);
  f.cr.setTo(0);
  EXPECT_EQ(convert_cpu(f.view(kBt709)).at<cv::Vec4b>(1, 1)[0], 0);
}

// The BT.601 limited-range numbers GStreamer's own converter test uses for I420 (Y 128, U 100,
// V 160; see tests/elements/test_stitchsync.cpp) from the textbook formula.
TEST(Convert, Bt601ReferenceValue) {
  Yuv420 f = to_yuv420(cv::Mat(4, 4, CV_8UC4, cv::Scalar::all(0)), FrameFormat::I420, kBt601);
  f.y.setTo(128);
  f.cb.setTo(100);
  f.cr.setTo(160);
  const cv::Vec4b got = convert_cpu(f.view(kBt601)).at<cv::Vec4b>(2, 2);
  const double yn = (128 - 16) / 219.0, un = (100 - 128) / 224.0, vn = (160 - 128) / 224.0;
  const double kr = 0.299, kb = 0.114, kg = 1 - kr - kb;
  EXPECT_NEAR(got[0], 255 * (yn + 2 * (1 - kr) * vn), 0.51);
  EXPECT_NEAR(got[1], 255 * (yn - 2 * kb * (1 - kb) / kg * un - 2 * kr * (1 - kr) / kg * vn), 0.51);
  EXPECT_NEAR(got[2], 255 * (yn + 2 * (1 - kb) * un), 0.51);
}

// Chroma is interpolated at its siting: co-sited columns take a sample as is and the columns in
// between the mean of two; NV12 and I420 holding the same samples give the same frame.
TEST(Convert, ChromaSitingAndLayouts) {
  Yuv420 f = to_yuv420(cv::Mat(2, 8, CV_8UC4, cv::Scalar::all(0)), FrameFormat::I420, kBt709);
  f.y.setTo(126);
  f.cb.setTo(128);
  const uint8_t cr[4] = {128, 128, 170, 170};
  for (int i = 0; i < 4; ++i) f.cr.at<uint8_t>(0, i) = cr[i];
  YuvColorimetry cosited = kBt709, centred = kBt709;
  cosited.chroma_cosited_x = true;
  centred.chroma_cosited_x = false;
  const cv::Mat a = convert_cpu(f.view(cosited)), b = convert_cpu(f.view(centred));
  // Red rises with Cr: left of the step as at 128, right as at 170, in between half-way.
  const int lo = a.at<cv::Vec4b>(0, 0)[0], hi = a.at<cv::Vec4b>(0, 4)[0];
  EXPECT_LT(lo + 40, hi);
  EXPECT_EQ(a.at<cv::Vec4b>(0, 2)[0], lo);                     // co-sited on a 128 sample
  EXPECT_NEAR(a.at<cv::Vec4b>(0, 3)[0], (lo + hi) / 2.0, 1);    // between 128 and 170
  EXPECT_NEAR(b.at<cv::Vec4b>(0, 3)[0], (3 * lo + hi) / 4.0, 1);  // centred: 3/4 + 1/4
  EXPECT_NEAR(b.at<cv::Vec4b>(0, 4)[0], (lo + 3 * hi) / 4.0, 1);
  Yuv420 nv = to_yuv420(cv::Mat(2, 8, CV_8UC4, cv::Scalar::all(0)), FrameFormat::NV12, kBt709);
  f.y.copyTo(nv.y);
  for (int i = 0; i < 4; ++i) {
    nv.uv.at<uint8_t>(0, 2 * i) = f.cb.at<uint8_t>(0, i);
    nv.uv.at<uint8_t>(0, 2 * i + 1) = f.cr.at<uint8_t>(0, i);
  }
  EXPECT_EQ(cv::norm(convert_cpu(nv.view(cosited)), a, cv::NORM_INF), 0.0);
}

// 4-byte RGB formats: copied, swizzled, padding made opaque.
TEST(Convert, RgbFormats) {
  cv::Mat in(3, 5, CV_8UC4, cv::Scalar(10, 20, 30, 40));
  FrameView v;
  v.width = in.cols;
  v.height = in.rows;
  v.planes[0] = in.data;
  v.pitches[0] = in.step;
  const std::pair<FrameFormat, cv::Vec4b> cases[] = {{FrameFormat::RGBA, {10, 20, 30, 40}},
                                                     {FrameFormat::RGBx, {10, 20, 30, 255}},
                                                     {FrameFormat::BGRA, {30, 20, 10, 40}},
                                                     {FrameFormat::BGRx, {30, 20, 10, 255}}};
  for (const auto& [format, want] : cases) {
    v.format = format;
    const cv::Mat out = convert_cpu(v);
    EXPECT_EQ(out.at<cv::Vec4b>(2, 4), want) << int(format);
  }
  v.format = FrameFormat::RGBA;
  cv::Mat small(2, 5, CV_8UC4);
  EXPECT_THROW(FrameConverter::create(Backend::Cpu)->convert(v, as_view(small)), std::invalid_argument);
}

#ifdef STITCH_HAVE_CUDA
namespace {

using testdata::test_photo;

// Device copies of a frame's planes / an RGBA image.
struct DevicePlanes {
  std::vector<void*> ptrs;
  ~DevicePlanes() {
    for (void* p : ptrs) cudaFree(p);
  }
  const uint8_t* upload(const cv::Mat& m, std::size_t& pitch) {
    void* p = nullptr;
    EXPECT_EQ(cudaMallocPitch(&p, &pitch, m.cols * m.elemSize(), std::size_t(m.rows)), cudaSuccess);
    EXPECT_EQ(cudaMemcpy2D(p, pitch, m.data, m.step, m.cols * m.elemSize(), std::size_t(m.rows), cudaMemcpyHostToDevice),
              cudaSuccess);
    ptrs.push_back(p);
    return static_cast<const uint8_t*>(p);
  }
  ImageView image(int width, int height) {
    void* p = nullptr;
    std::size_t pitch = 0;
    EXPECT_EQ(cudaMallocPitch(&p, &pitch, std::size_t(width) * 4, std::size_t(height)), cudaSuccess);
    EXPECT_EQ(cudaMemset2D(p, pitch, 77, std::size_t(width) * 4, std::size_t(height)), cudaSuccess);  // poisoned
    ptrs.push_back(p);
    ImageView v;
    v.data = static_cast<uint8_t*>(p);
    v.pitch = pitch;
    v.width = width;
    v.height = height;
    v.on_device = true;
    return v;
  }
};

cv::Mat download(const ImageView& v) {
  cv::Mat m(v.height, v.width, CV_8UC4);
  EXPECT_EQ(cudaMemcpy2D(m.data, m.step, v.data, v.pitch, std::size_t(v.width) * 4, std::size_t(v.height),
                         cudaMemcpyDeviceToHost),
            cudaSuccess);
  return m;
}

// The frame with every plane moved to the device.
FrameView on_device(const FrameView& in, const std::vector<cv::Mat>& planes, DevicePlanes& dev) {
  FrameView d = in;
  d.on_device = true;
  for (std::size_t p = 0; p < planes.size(); ++p) d.planes[p] = dev.upload(planes[p], d.pitches[p]);
  return d;
}

}  // namespace
#endif

// CUDA vs CPU on a real photo at an odd size, for every layout and both memories on each side.
TEST(CudaConvert, MatchesCpu) {
  REQUIRE_CUDA();
#ifdef STITCH_HAVE_CUDA
  cv::Mat rgba;
  cv::resize(test_photo()(cv::Rect(100, 100, 1280, 720)), rgba, cv::Size(641, 359), 0, 0, cv::INTER_AREA);
  auto gpu = FrameConverter::create(Backend::Cuda);
  ASSERT_EQ(gpu->backend(), Backend::Cuda);
  for (FrameFormat format : {FrameFormat::NV12, FrameFormat::I420, FrameFormat::RGBA, FrameFormat::BGRx}) {
    for (const YuvColorimetry& c : {kBt601, kBt709}) {
      FrameView host;
      std::vector<cv::Mat> planes;
      Yuv420 yuv;
      cv::Mat rgb4;
      if (is_yuv420(format)) {
        yuv = to_yuv420(rgba, format, c);
        host = yuv.view(c);
        planes = format == FrameFormat::NV12 ? std::vector<cv::Mat>{yuv.y, yuv.uv} : std::vector<cv::Mat>{yuv.y, yuv.cb, yuv.cr};
      } else {
        if (format == FrameFormat::BGRx) cv::cvtColor(rgba, rgb4, cv::COLOR_RGBA2BGRA);
        else rgb4 = rgba.clone();
        host.format = format;
        host.width = rgb4.cols;
        host.height = rgb4.rows;
        host.planes[0] = rgb4.data;
        host.pitches[0] = rgb4.step;
        planes = {rgb4};
      }
      const cv::Mat expected = convert_cpu(host);
      DevicePlanes dev;
      const FrameView device = on_device(host, planes, dev);
      for (const FrameView& in : {host, device}) {
        cv::Mat to_host(rgba.rows, rgba.cols, CV_8UC4, cv::Scalar::all(77));
        const ImageView to_dev = dev.image(rgba.cols, rgba.rows);
        gpu->convert(in, as_view(to_host));
        gpu->convert(in, to_dev);
        gpu->finish();
        const double ph = testdata::psnr_rgb(to_host, expected), pd = testdata::psnr_rgb(download(to_dev), expected);
        std::printf("convert format %d kr %.4f from %s: CUDA vs CPU PSNR %.2f dB (to system), %.2f dB (to device)\n",
                    int(format), c.kr, in.on_device ? "device" : "system", ph, pd);
        EXPECT_GE(ph, 45.0);
        EXPECT_GE(pd, 45.0);
        EXPECT_EQ(cv::norm(download(to_dev), expected, cv::NORM_INF), 0.0) << "the same integer math should agree exactly";
      }
    }
  }
  // The photo itself survives the round trip through NV12 (the 4:2:0 subsampling costs detail).
  const Yuv420 nv12 = to_yuv420(rgba, FrameFormat::NV12, kBt709);
  cv::Mat back(rgba.rows, rgba.cols, CV_8UC4);
  gpu->convert(nv12.view(kBt709), as_view(back));
  gpu->finish();
  const double psnr = testdata::psnr_rgb(back, rgba);
  std::printf("photo through NV12 and back: PSNR %.2f dB\n", psnr);
  EXPECT_GE(psnr, 30.0);
#endif
}

// clear() writes transparent black on the device.
TEST(CudaConvert, ClearIsTransparentBlack) {
  REQUIRE_CUDA();
#ifdef STITCH_HAVE_CUDA
  auto gpu = FrameConverter::create(Backend::Cuda);
  DevicePlanes dev;
  const ImageView v = dev.image(33, 17);
  gpu->clear(v);
  gpu->finish();
  EXPECT_EQ(cv::countNonZero(download(v).reshape(1)), 0);
#endif
}

// Time alignment's vision signal on CUDA-memory inputs: the frame is reduced to its 64x36
// thumbnail on the device (stitch/sync/thumbnail.hpp). It must equal the CPU's bit for bit,
// or the two paths would estimate different offsets from the same cameras.
#include "stitch/sync/thumbnail.hpp"

TEST(CudaConvert, TimeAlignThumbnailEqualsCpu) {
  REQUIRE_CUDA_FOR("the time-alignment thumbnail");
#ifdef STITCH_HAVE_CUDA
  for (const cv::Size size : {cv::Size(1920, 1080), cv::Size(641, 359), cv::Size(50, 20)}) {
    cv::Mat rgba(size, CV_8UC4);
    cv::randu(rgba, cv::Scalar::all(0), cv::Scalar::all(256));
    testdata::DeviceMat dev(rgba);
    for (int channel : {0, 1}) {
      std::vector<float> cpu(stitch::sync::kThumbnailW * stitch::sync::kThumbnailH),
          gpu(cpu.size(), -1.f);
      stitch::sync::frame_thumbnail_cpu(rgba.data, size.width, size.height, rgba.step, 4, channel, cpu.data());
      stitch::sync::FrameThumbnailerCuda thumbnailer;
      thumbnailer.thumbnail(dev.ptr, size.width, size.height, dev.pitch, 4, channel, gpu.data());
      for (std::size_t i = 0; i < cpu.size(); ++i)
        ASSERT_EQ(cpu[i], gpu[i]) << size << " channel " << channel << " cell " << i;
    }
  }
#endif
}

// The element's asynchronous path (submit now, take a bundle later; issue 18): the readback
// goes to page-locked memory behind an event. Several views in flight at once, each slot reused
// for the next frame, must give the CPU's thumbnails bit for bit, in the slot they were queued in.
TEST(CudaConvert, TimeAlignAsyncThumbnailEqualsCpu) {
  REQUIRE_CUDA_FOR("the asynchronous time-alignment thumbnail");
#ifdef STITCH_HAVE_CUDA
  const std::size_t cells = std::size_t(stitch::sync::kThumbnailW) * stitch::sync::kThumbnailH;
  stitch::sync::FrameThumbnailerCuda thumbnailer;
  std::vector<cv::Mat> frames;
  std::vector<std::unique_ptr<testdata::DeviceMat>> dev;
  for (int k = 0; k < 6; ++k) {  // 3 views x 2 frames
    cv::Mat rgba(cv::Size(640 + 17 * k, 360 + 5 * k), CV_8UC4);
    cv::randu(rgba, cv::Scalar::all(0), cv::Scalar::all(256));
    frames.push_back(rgba);
    dev.push_back(std::make_unique<testdata::DeviceMat>(rgba));
  }
  EXPECT_FALSE(thumbnailer.pending(0));
  std::vector<float> got(cells, -1.f), want(cells);
  EXPECT_FALSE(thumbnailer.take(0, got.data()));
  for (int round = 0; round < 2; ++round) {
    for (int v = 0; v < 3; ++v) {
      const testdata::DeviceMat& d = *dev[std::size_t(round * 3 + v)];
      thumbnailer.submit(v, d.ptr, frames[std::size_t(round * 3 + v)].cols, frames[std::size_t(round * 3 + v)].rows,
                         d.pitch, 4, 1);
      EXPECT_TRUE(thumbnailer.pending(v));
    }
    for (int v = 2; v >= 0; --v) {  // taken in another order than queued
      const cv::Mat& f = frames[std::size_t(round * 3 + v)];
      stitch::sync::frame_thumbnail_cpu(f.data, f.cols, f.rows, f.step, 4, 1, want.data());
      ASSERT_TRUE(thumbnailer.take(v, got.data())) << v;
      EXPECT_FALSE(thumbnailer.pending(v));
      for (std::size_t i = 0; i < cells; ++i) ASSERT_EQ(want[i], got[i]) << "round " << round << " view " << v << " cell " << i;
    }
  }
  // a slot resubmitted before it was taken holds the newer frame
  thumbnailer.submit(1, dev[0]->ptr, frames[0].cols, frames[0].rows, dev[0]->pitch, 4, 1);
  thumbnailer.submit(1, dev[4]->ptr, frames[4].cols, frames[4].rows, dev[4]->pitch, 4, 1);
  stitch::sync::frame_thumbnail_cpu(frames[4].data, frames[4].cols, frames[4].rows, frames[4].step, 4, 1, want.data());
  ASSERT_TRUE(thumbnailer.take(1, got.data()));
  EXPECT_EQ(want, got);
#endif
}
