// stitchbin: the issue's launch line runs (videotestsrc cameras into s.sink_N), the proxied
// properties reach the children, and real crops come out as the expected panorama.
#include <gtest/gtest.h>

#include "gst_helpers.hpp"
#include "stitch/rig/rig.hpp"
#include "test_data.hpp"

using namespace stitch;

namespace {

// Runs `description` to EOS (or an error, or 60 s); counts the buffers reaching fakesink "out".
struct Outcome {
  bool eos = false;
  std::string error;
  int buffers = 0;
};

Outcome run_to_eos(const std::string& description) {
  gsttest::init();
  Outcome o;
  GError* err = nullptr;
  GstElement* pipe = gst_parse_launch(description.c_str(), &err);
  if (!pipe) {
    o.error = err ? err->message : "parse failed";
    g_clear_error(&err);
    return o;
  }
  if (GstElement* sink = gst_bin_get_by_name(GST_BIN(pipe), "out")) {
    g_object_set(sink, "signal-handoffs", TRUE, NULL);
    g_signal_connect(sink, "handoff", G_CALLBACK(+[](GstElement*, GstBuffer*, GstPad*, gpointer n) {
                       ++*static_cast<int*>(n);
                     }),
                     &o.buffers);
    gst_object_unref(sink);
  }
  gst_element_set_state(pipe, GST_STATE_PLAYING);
  GstBus* bus = gst_element_get_bus(pipe);
  GstMessage* m = gst_bus_timed_pop_filtered(bus, 60 * GST_SECOND, GstMessageType(GST_MESSAGE_ERROR | GST_MESSAGE_EOS));
  if (!m) {
    o.error = "no EOS within 60 s";
  } else if (GST_MESSAGE_TYPE(m) == GST_MESSAGE_ERROR) {
    GError* e = nullptr;
    gst_message_parse_error(m, &e, nullptr);
    o.error = e ? e->message : "error";
    g_clear_error(&e);
  } else {
    o.eos = true;
  }
  if (m) gst_message_unref(m);
  gst_object_unref(bus);
  gst_element_set_state(pipe, GST_STATE_NULL);
  gst_object_unref(pipe);
  return o;
}

// The nick of an enum property's current value ("multiband", "dp", ...).
std::string enum_nick(GstElement* e, const char* property) {
  GValue v = G_VALUE_INIT;
  GParamSpec* spec = g_object_class_find_property(G_OBJECT_GET_CLASS(e), property);
  if (!spec || !G_IS_PARAM_SPEC_ENUM(spec)) return "(no enum property " + std::string(property) + ")";
  g_value_init(&v, spec->value_type);
  g_object_get_property(G_OBJECT(e), property, &v);
  GEnumValue* ev = g_enum_get_value(G_PARAM_SPEC_ENUM(spec)->enum_class, g_value_get_enum(&v));
  g_value_unset(&v);
  return ev ? ev->value_nick : "?";
}

}  // namespace

TEST(StitchBin, TheIssueLaunchLineRuns) {
  // `... ! stitchbin name=s ! autovideosink  src0 ! s.sink_0  src1 ! s.sink_1`, with two test
  // sources (calibrated from a rough rig: test patterns have no features to match) and fakesink.
  const std::string rig = testdata::repo_path("examples/limlight_rig.json");
  const std::string caps = "video/x-raw,width=720,height=404,framerate=30/1";
  const Outcome o = run_to_eos("stitchbin name=s rig-file=" + rig + " refine=none ! fakesink name=out " +
                               "videotestsrc num-buffers=5 ! " + caps + " ! s.sink_0 " +
                               "videotestsrc num-buffers=5 pattern=ball ! " + caps + " ! s.sink_1");
  EXPECT_TRUE(o.eos) << o.error;
  EXPECT_EQ(o.buffers, 5);
}

// stitchsync's thread uploads the next bundle while the stages work on this one: a queue sits
// between calib and color (the throughput of system-memory inputs depends on it).
TEST(StitchBin, AQueueSeparatesStitchsyncsThreadFromTheStages) {
  gsttest::init();
  GstElement* bin = gst_element_factory_make("stitchbin", nullptr);
  ASSERT_NE(bin, nullptr);
  GstElement* queue = gst_bin_get_by_name(GST_BIN(bin), "queue");
  ASSERT_NE(queue, nullptr);
  GstPad* in = gst_element_get_static_pad(queue, "sink");
  GstPad* out = gst_element_get_static_pad(queue, "src");
  GstPad* from = gst_pad_get_peer(in);
  GstPad* to = gst_pad_get_peer(out);
  ASSERT_TRUE(from && to);
  GstElement* up = gst_pad_get_parent_element(from);
  GstElement* down = gst_pad_get_parent_element(to);
  EXPECT_STREQ(GST_ELEMENT_NAME(up), "calib");
  EXPECT_STREQ(GST_ELEMENT_NAME(down), "color");
  guint buffers = 0;
  g_object_get(queue, "max-size-buffers", &buffers, NULL);
  EXPECT_EQ(buffers, 2u);
  for (GstObject* o : {GST_OBJECT(up), GST_OBJECT(down), GST_OBJECT(from), GST_OBJECT(to), GST_OBJECT(in),
                       GST_OBJECT(out), GST_OBJECT(queue)})
    gst_object_unref(o);
  gst_object_unref(bin);
}

TEST(StitchBin, PropertiesReachTheChildren) {
  gsttest::init();
  GError* err = nullptr;
  GstElement* pipe = gst_parse_launch(
      "stitchbin name=s mode=multiband seam=dp bands=4 crop=auto method=gain flow=false "
      "calib::features=orb backend=cpu ! fakesink",
      &err);
  ASSERT_NE(pipe, nullptr) << (err ? err->message : "");
  GstElement* bin = gst_bin_get_by_name(GST_BIN(pipe), "s");
  ASSERT_NE(bin, nullptr);
  GstElement* blend = gst_bin_get_by_name(GST_BIN(bin), "blend");
  GstElement* color = gst_bin_get_by_name(GST_BIN(bin), "color");
  GstElement* flow = gst_bin_get_by_name(GST_BIN(bin), "flowwarp");
  GstElement* calib = gst_bin_get_by_name(GST_BIN(bin), "calib");
  GstElement* sync = gst_bin_get_by_name(GST_BIN(bin), "sync");
  ASSERT_TRUE(blend && color && flow && calib && sync);
  gint bands = 0, bin_bands = 0;
  gboolean flow_on = TRUE;
  g_object_get(blend, "bands", &bands, NULL);
  g_object_get(bin, "bands", &bin_bands, NULL);
  g_object_get(flow, "flow", &flow_on, NULL);
  EXPECT_EQ(bands, 4);
  EXPECT_EQ(bin_bands, 4);
  EXPECT_EQ(enum_nick(blend, "mode"), "multiband");
  EXPECT_EQ(enum_nick(bin, "mode"), "multiband");
  EXPECT_EQ(enum_nick(blend, "seam"), "dp");
  EXPECT_EQ(enum_nick(blend, "crop"), "auto");
  EXPECT_EQ(enum_nick(color, "method"), "gain");
  EXPECT_FALSE(flow_on);
  EXPECT_EQ(enum_nick(calib, "features"), "orb");  // through GstChildProxy
  for (GstElement* e : {blend, color, flow, calib, sync}) EXPECT_EQ(enum_nick(e, "backend"), "cpu");
  for (GstElement* e : {blend, color, flow, calib, sync}) gst_object_unref(e);
  gst_object_unref(bin);
  gst_object_unref(pipe);
}

TEST(StitchBin, StitchesRealCropsIntoThePanorama) {
  const auto [photo, views, calib] = testdata::boat_crops("bin_exact.json");
  gsttest::RunResult r;
  gsttest::run_pipeline("stitchbin name=s load-file=" + calib +
                            " mode=multiband seam=dp ! appsink name=out sync=false" + gsttest::appsrc_inputs(2),
                        views, 3, r);
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  ASSERT_EQ(r.frames.size(), 3u);
  ASSERT_EQ(r.frames[0].cols, 1040);
  ASSERT_EQ(r.frames[0].rows, 480);
  // Consistent crops, color-corrected and flow-warped to no change, multiband-blended: the photo.
  EXPECT_GT(testdata::psnr_rgb(r.frames.back(), photo(cv::Rect(0, 200, 1040, 480))), 38.0);
}

// probe6: the bin's source pad advertises any raw video, but stitchblend makes RGBA only:
// `stitchbin ! x264enc`, `stitchbin ! jpegenc` and `stitchbin ! video/x-raw,format=I420` did not
// link ("could not link s to x264enc0"). A videoconvert named convert after blend converts for
// them (and passes RGBA through for the others).
TEST(StitchBin, GivesTheFormatDownstreamAsksFor) {
  const auto [photo, views, calib] = testdata::boat_crops("bin_exact.json");
  gsttest::RunResult r;
  gsttest::run_pipeline("stitchbin name=s load-file=" + calib +
                            " ! video/x-raw,format=I420 ! videoconvert ! video/x-raw,format=RGBA ! "
                            "appsink name=out sync=false" + gsttest::appsrc_inputs(2),
                        views, 2, r);
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  ASSERT_EQ(r.frames.size(), 2u);
  ASSERT_EQ(r.frames[1].cols, 1040);
  ASSERT_EQ(r.frames[1].rows, 480);
  EXPECT_GT(testdata::psnr_rgb(r.frames[1], photo(cv::Rect(0, 200, 1040, 480))), 30.0);  // 4:2:0 round trip
  // A size downstream fixes still reaches stitchblend through the converter (which takes any
  // size itself): the width alone keeps the panorama's aspect, 480 * 1001 / 1040 = 462.
  gsttest::RunResult sized;
  gsttest::run_pipeline("stitchbin name=s load-file=" + calib + " ! video/x-raw,width=1001 ! appsink name=out sync=false" +
                            gsttest::appsrc_inputs(2),
                        views, 2, sized);
  ASSERT_TRUE(sized.errors.empty()) << sized.errors[0];
  ASSERT_EQ(sized.frames.size(), 2u);
  EXPECT_EQ(sized.frames[1].cols, 1001);
  EXPECT_EQ(sized.frames[1].rows, 462);
  gsttest::init();
  GstElement* bin = gst_element_factory_make("stitchbin", nullptr);
  ASSERT_NE(bin, nullptr);
  GstElement* convert = gst_bin_get_by_name(GST_BIN(bin), "convert");
  ASSERT_NE(convert, nullptr);
  GstPad* in = gst_element_get_static_pad(convert, "sink");
  GstPad* from = gst_pad_get_peer(in);
  ASSERT_NE(from, nullptr);
  GstElement* up = gst_pad_get_parent_element(from);
  EXPECT_STREQ(GST_ELEMENT_NAME(up), "blend");
  for (GstObject* o : {GST_OBJECT(up), GST_OBJECT(from), GST_OBJECT(in), GST_OBJECT(convert)}) gst_object_unref(o);
  gst_object_unref(bin);
}

// Issue 18: every property a user of the chain sets is the bin's, found from the children's
// specs (a property a child gains appears with no code): same type, default and mutability.
TEST(StitchBin, ExposesEveryChildPropertyWithItsFlags) {
  gsttest::init();
  GstElement* bin = gst_element_factory_make("stitchbin", NULL);
  ASSERT_NE(bin, nullptr);
  GObjectClass* bin_class = G_OBJECT_GET_CLASS(bin);
  for (const char* name : {"dropout", "dropout-timeout", "force-live", "reference", "features", "latency",
                           "memory-limit", "on-resize", "projection", "temporal-smoothing", "lambda"})
    EXPECT_NE(g_object_class_find_property(bin_class, name), nullptr) << name;
  const GParamFlags mutable_flags =
      GParamFlags(GST_PARAM_MUTABLE_READY | GST_PARAM_MUTABLE_PAUSED | GST_PARAM_MUTABLE_PLAYING);
  int checked = 0;
  for (const char* child_name : {"sync", "calib", "color", "flowwarp", "blend"}) {
    GstElement* child = gst_bin_get_by_name(GST_BIN(bin), child_name);
    ASSERT_NE(child, nullptr) << child_name;
    guint n = 0;
    GParamSpec** specs = g_object_class_list_properties(G_OBJECT_GET_CLASS(child), &n);
    for (guint i = 0; i < n; ++i) {
      GParamSpec* c = specs[i];
      if (c->owner_type != G_OBJECT_TYPE(child) || !(c->flags & G_PARAM_WRITABLE)) continue;
      GParamSpec* b = g_object_class_find_property(bin_class, c->name);
      ASSERT_NE(b, nullptr) << child_name << "::" << c->name << " is not the bin's";
      EXPECT_EQ(b->value_type, c->value_type) << c->name;
      // shared by several children: the strictest child's flags, and the bin's own blurb
      if (g_strcmp0(c->name, "backend") != 0 && g_strcmp0(c->name, "load-file") != 0) {
        EXPECT_EQ(b->flags & mutable_flags, c->flags & mutable_flags) << c->name;
        EXPECT_STREQ(g_param_spec_get_blurb(b), g_param_spec_get_blurb(c)) << c->name;
      }
      GValue bv = G_VALUE_INIT, cv = G_VALUE_INIT;
      g_value_init(&bv, b->value_type);
      g_value_init(&cv, c->value_type);
      g_object_get_property(G_OBJECT(bin), c->name, &bv);
      g_object_get_property(G_OBJECT(child), c->name, &cv);
      EXPECT_EQ(gst_value_compare(&bv, &cv), GST_VALUE_EQUAL) << c->name;
      g_value_unset(&bv);
      g_value_unset(&cv);
      ++checked;
    }
    g_free(specs);
    gst_object_unref(child);
  }
  EXPECT_GT(checked, 35);
  // per-frame properties stay changeable while playing
  EXPECT_TRUE(g_object_class_find_property(bin_class, "debug")->flags & GST_PARAM_MUTABLE_PLAYING);
  EXPECT_TRUE(g_object_class_find_property(bin_class, "smoothing")->flags & GST_PARAM_MUTABLE_PLAYING);
  gst_object_unref(bin);
}

TEST(StitchBin, NewlyProxiedPropertiesReachTheChildren) {
  gsttest::init();
  GError* err = nullptr;
  GstElement* pipe = gst_parse_launch(
      "stitchbin name=s force-live=true dropout=fill dropout-timeout=123000000 reference=0 features=orb "
      "memory-limit=100 ! fakesink",
      &err);
  ASSERT_NE(pipe, nullptr) << (err ? err->message : "");
  GstElement* bin = gst_bin_get_by_name(GST_BIN(pipe), "s");
  GstElement* sync = gst_bin_get_by_name(GST_BIN(bin), "sync");
  GstElement* calib = gst_bin_get_by_name(GST_BIN(bin), "calib");
  GstElement* blend = gst_bin_get_by_name(GST_BIN(bin), "blend");
  gboolean live = FALSE;
  guint64 timeout = 0;
  gint reference = -1;
  guint limit = 0;
  g_object_get(sync, "force-live", &live, "dropout-timeout", &timeout, NULL);
  g_object_get(calib, "reference", &reference, NULL);
  g_object_get(blend, "memory-limit", &limit, NULL);
  EXPECT_TRUE(live);
  EXPECT_EQ(timeout, 123000000u);
  EXPECT_EQ(reference, 0);
  EXPECT_EQ(limit, 100u);
  EXPECT_EQ(enum_nick(sync, "dropout"), "fill");
  EXPECT_EQ(enum_nick(calib, "features"), "orb");
  for (GstElement* e : {sync, calib, blend, bin}) gst_object_unref(e);
  gst_object_unref(pipe);
}

// Issue 18: properties read on every frame may change while playing (the numbers may follow a
// GstControlSource on the element), the backend only before the memory is negotiated; each
// element's klass says what it does.
TEST(StitchElements, PerFramePropertiesAndKlassSayWhatTheElementsDo) {
  gsttest::init();
  struct Expect {
    const char* element;
    const char* property;
    GParamFlags flags;
  };
  const GParamFlags playing = GParamFlags(GST_PARAM_MUTABLE_PLAYING);
  const GParamFlags controllable = GParamFlags(GST_PARAM_MUTABLE_PLAYING | GST_PARAM_CONTROLLABLE);
  const GParamFlags ready = GParamFlags(GST_PARAM_MUTABLE_READY);
  for (const Expect& e : std::vector<Expect>{{"stitchcolor", "method", playing},
                                              {"stitchcolor", "smoothing", controllable},
                                              {"stitchcolor", "lambda", controllable},
                                              {"stitchcolor", "backend", ready},
                                              {"stitchflowwarp", "flow", playing},
                                              {"stitchflowwarp", "temporal-smoothing", controllable},
                                              {"stitchflowwarp", "backend", ready},
                                              {"stitchblend", "debug", controllable},
                                              {"stitchblend", "output-width", playing},
                                              {"stitchblend", "mode", playing},
                                              {"stitchblend", "backend", ready}}) {
    GstElementFactory* f = gst_element_factory_find(e.element);
    ASSERT_NE(f, nullptr) << e.element;
    GstPluginFeature* loaded = gst_plugin_feature_load(GST_PLUGIN_FEATURE(f));
    GObjectClass* klass = G_OBJECT_CLASS(g_type_class_ref(gst_element_factory_get_element_type(GST_ELEMENT_FACTORY(loaded))));
    GParamSpec* spec = g_object_class_find_property(klass, e.property);
    ASSERT_NE(spec, nullptr) << e.element << "::" << e.property;
    EXPECT_EQ(spec->flags & e.flags, e.flags) << e.element << "::" << e.property;
    g_type_class_unref(klass);
    gst_object_unref(loaded);
    gst_object_unref(f);
  }
  const std::vector<std::pair<const char*, const char*>> klasses = {
      {"stitchsync", "Video/Combiner"},          {"stitchcalib", "Filter/Analyzer/Video"},
      {"stitchcolor", "Filter/Effect/Video"},    {"stitchflowwarp", "Filter/Converter/Video"},
      {"stitchblend", "Filter/Converter/Video"}, {"stitchbin", "Video/Combiner"}};
  for (const auto& [element, klass] : klasses) {
    GstElementFactory* f = gst_element_factory_find(element);
    ASSERT_NE(f, nullptr) << element;
    EXPECT_STREQ(gst_element_factory_get_metadata(f, GST_ELEMENT_METADATA_KLASS), klass) << element;
    gst_object_unref(f);
  }
}
