// stitch360sink (issue 15): the written MP4 carries Spherical Video V2 boxes in the video sample
// entry and the V1 XML uuid box in the video trak, read back by a box parser written here; with
// moov first (mp4mux faststart) the chunk offsets still point at the frames (it decodes).
#include <gtest/gtest.h>

#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "gst_helpers.hpp"

namespace {

struct Box {
  std::string path;  // e.g. "moov/trak/mdia/minf/stbl/stsd/avc1/sv3d"
  std::size_t offset, size;
};

uint32_t be32(const std::vector<uint8_t>& d, std::size_t at) {
  return uint32_t(d[at]) << 24 | uint32_t(d[at + 1]) << 16 | uint32_t(d[at + 2]) << 8 | d[at + 3];
}

// A small ISO-BMFF parser: containers we need to descend, sizes checked against the parent.
void parse(const std::vector<uint8_t>& d, std::size_t from, std::size_t to, const std::string& parent,
           std::vector<Box>& out) {
  std::size_t p = from;
  while (p + 8 <= to) {
    std::size_t size = be32(d, p);
    const std::string type(reinterpret_cast<const char*>(&d[p + 4]), 4);
    std::size_t header = 8;
    if (size == 1) {
      size = std::size_t(be32(d, p + 8)) << 32 | be32(d, p + 12);
      header = 16;
    }
    ASSERT_GE(size, header) << type;
    ASSERT_LE(p + size, to) << parent << "/" << type << " overruns its parent";
    const std::string path = parent.empty() ? type : parent + "/" + type;
    out.push_back({path, p, size});
    std::size_t child = 0;
    if (type == "moov" || type == "trak" || type == "mdia" || type == "minf" || type == "stbl" || type == "sv3d" ||
        type == "proj")
      child = header;
    else if (type == "stsd")
      child = header + 8;
    else if (type == "avc1")
      child = header + 78;
    if (child) parse(d, p + child, p + size, path, out);
    p += size;
  }
  EXPECT_EQ(p, to) << "boxes of " << parent << " do not fill it";
}

std::vector<uint8_t> read_all(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::vector<uint8_t>((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
}

const Box* find(const std::vector<Box>& boxes, const std::string& path) {
  for (const auto& b : boxes)
    if (b.path == path) return &b;
  return nullptr;
}

// Runs the pipeline to EOS; returns the error text (empty on success).
std::string run(const std::string& description) {
  gsttest::init();
  GError* err = nullptr;
  GstElement* pipe = gst_parse_launch(description.c_str(), &err);
  if (!pipe) {
    std::string e = err ? err->message : "parse failed";
    g_clear_error(&err);
    return e;
  }
  gst_element_set_state(pipe, GST_STATE_PLAYING);
  GstBus* bus = gst_element_get_bus(pipe);
  GstMessage* m = gst_bus_timed_pop_filtered(bus, 60 * GST_SECOND, GstMessageType(GST_MESSAGE_ERROR | GST_MESSAGE_EOS));
  std::string error;
  if (!m) error = "timeout";
  else if (GST_MESSAGE_TYPE(m) == GST_MESSAGE_ERROR) {
    GError* e = nullptr;
    gst_message_parse_error(m, &e, nullptr);
    error = e->message;
    g_error_free(e);
  }
  if (m) gst_message_unref(m);
  gst_object_unref(bus);
  gst_element_set_state(pipe, GST_STATE_NULL);
  gst_object_unref(pipe);
  return error;
}

// Runs the pipeline to EOS; the texts of its warning messages.
std::vector<std::string> warnings_of(const std::string& description) {
  gsttest::init();
  std::vector<std::string> out;
  GstElement* pipe = gst_parse_launch(description.c_str(), nullptr);
  if (!pipe) return {"parse failed"};
  gst_element_set_state(pipe, GST_STATE_PLAYING);
  GstBus* bus = gst_element_get_bus(pipe);
  for (;;) {
    GstMessage* m = gst_bus_timed_pop_filtered(
        bus, 60 * GST_SECOND, GstMessageType(GST_MESSAGE_ERROR | GST_MESSAGE_EOS | GST_MESSAGE_WARNING));
    if (!m) break;
    const GstMessageType t = GST_MESSAGE_TYPE(m);
    if (t == GST_MESSAGE_WARNING) {
      GError* e = nullptr;
      gst_message_parse_warning(m, &e, nullptr);
      out.push_back(e->message);
      g_error_free(e);
    }
    gst_message_unref(m);
    if (t != GST_MESSAGE_WARNING) break;
  }
  gst_object_unref(bus);
  gst_element_set_state(pipe, GST_STATE_NULL);
  gst_object_unref(pipe);
  return out;
}

bool have(const char* factory) {
  gsttest::init();
  GstElementFactory* f = gst_element_factory_find(factory);
  if (f) gst_object_unref(f);
  return f != nullptr;
}

}  // namespace

TEST(Stitch360Sink, WritesSphericalV1AndV2Boxes) {
  if (!have("x264enc") || !have("mp4mux")) GTEST_SKIP() << "x264enc or mp4mux missing";
  for (const char* faststart : {"false", "true"}) {
    const std::string path =
        (std::filesystem::temp_directory_path() / ("stitch360_" + std::to_string(::getpid()) + faststart + ".mp4")).string();
    const std::string err = run("videotestsrc num-buffers=30 ! video/x-raw,width=512,height=256,format=I420 ! x264enc ! "
                                "stitch360sink mux::faststart=" + std::string(faststart) + " location=" + path);
    ASSERT_EQ(err, "") << faststart;
    const std::vector<uint8_t> d = read_all(path);
    std::vector<Box> boxes;
    parse(d, 0, d.size(), "", boxes);
    const std::string entry = "moov/trak/mdia/minf/stbl/stsd/avc1";
    ASSERT_TRUE(find(boxes, entry)) << faststart;
    EXPECT_TRUE(find(boxes, entry + "/st3d"));
    EXPECT_TRUE(find(boxes, entry + "/sv3d/svhd"));
    EXPECT_TRUE(find(boxes, entry + "/sv3d/proj/prhd"));
    const Box* equi = find(boxes, entry + "/sv3d/proj/equi");
    ASSERT_TRUE(equi);
    EXPECT_EQ(equi->size, 8u + 4u + 16u);
    const Box* uuid = find(boxes, "moov/trak/uuid");
    ASSERT_TRUE(uuid);
    const std::string body(reinterpret_cast<const char*>(&d[uuid->offset + 24]), uuid->size - 24);
    EXPECT_EQ(std::memcmp(&d[uuid->offset + 8], "\xff\xcc\x82\x63\xf8\x55\x4a\x93\x88\x14\x58\x7a\x02\x52\x1f\xdd", 16), 0);
    EXPECT_NE(body.find("<GSpherical:ProjectionType>equirectangular</GSpherical:ProjectionType>"), std::string::npos);
    EXPECT_NE(body.find("<GSpherical:FullPanoWidthPixels>512<"), std::string::npos);
    // The frames are still where the chunk offsets say: the file decodes to all 30.
    if (have("avdec_h264")) {
      const std::string dec = run("filesrc location=" + path + " ! qtdemux ! h264parse ! avdec_h264 ! fakesink");
      EXPECT_EQ(dec, "") << faststart;
    }
    std::filesystem::remove(path);
  }
}

// A cubemap rig's 3x2 output: V2 sv3d/proj/cbmp (layout 0, padding 0), no equi, no V1 box.
TEST(Stitch360Sink, WritesCubemapV2Box) {
  if (!have("x264enc") || !have("mp4mux")) GTEST_SKIP() << "x264enc or mp4mux missing";
  const std::string path = (std::filesystem::temp_directory_path() / ("stitch360_cbmp_" + std::to_string(::getpid()) + ".mp4")).string();
  const std::string err = run("videotestsrc num-buffers=10 ! video/x-raw,width=384,height=256,format=I420 ! x264enc ! "
                              "stitch360sink projection=cubemap location=" + path);
  ASSERT_EQ(err, "");
  const std::vector<uint8_t> d = read_all(path);
  std::vector<Box> boxes;
  parse(d, 0, d.size(), "", boxes);
  const std::string entry = "moov/trak/mdia/minf/stbl/stsd/avc1";
  EXPECT_TRUE(find(boxes, entry + "/st3d"));
  EXPECT_TRUE(find(boxes, entry + "/sv3d/proj/prhd"));
  EXPECT_FALSE(find(boxes, entry + "/sv3d/proj/equi"));
  const Box* cbmp = find(boxes, entry + "/sv3d/proj/cbmp");
  ASSERT_TRUE(cbmp);
  ASSERT_EQ(cbmp->size, 8u + 4u + 8u);
  for (int k = 12; k < 20; ++k) EXPECT_EQ(d[cbmp->offset + k], 0) << "layout 0, padding 0";
  EXPECT_FALSE(find(boxes, "moov/trak/uuid")) << "V1 has no cubemap";
  std::filesystem::remove(path);
}

// A panorama that is not 2:1 (a plane rig's, a 640x480 picture) marked as a 360 video is
// stretched over the sphere by every player: the file is written, and a warning says why it will
// look wrong (branch probe360: it was silent). A 2:1 one gets no warning.
TEST(Stitch360Sink, WarnsWhenThePanoramaIsNot2To1) {
  if (!have("x264enc") || !have("mp4mux")) GTEST_SKIP() << "x264enc or mp4mux missing";
  const std::string path = (std::filesystem::temp_directory_path() / ("stitch360_ratio_" + std::to_string(::getpid()) + ".mp4")).string();
  auto said = [](const std::vector<std::string>& w) {
    for (const auto& s : w)
      if (s.find("not 2:1") != std::string::npos && s.find("640x480") != std::string::npos) return true;
    return false;
  };
  const auto bad = warnings_of("videotestsrc num-buffers=5 ! video/x-raw,width=640,height=480,format=I420 ! x264enc ! "
                               "stitch360sink location=" + path);
  EXPECT_TRUE(said(bad)) << (bad.empty() ? "no warning" : bad[0]);
  EXPECT_TRUE(std::filesystem::exists(path));
  const auto good = warnings_of("videotestsrc num-buffers=5 ! video/x-raw,width=512,height=256,format=I420 ! x264enc ! "
                                "stitch360sink location=" + path);
  EXPECT_TRUE(good.empty()) << good[0];
  std::filesystem::remove(path);
}

TEST(Stitch360Sink, NoLocationIsAnError) {
  if (!have("x264enc")) GTEST_SKIP() << "x264enc missing";
  EXPECT_NE(run("videotestsrc num-buffers=2 ! x264enc ! stitch360sink"), "");
}
