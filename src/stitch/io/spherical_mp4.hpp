// Spherical Video metadata for MP4 files (issue 15): inserts Google's Spherical Video V2 boxes
// (`sv3d` { `svhd`, `proj` { `prhd`, `equi` } } in the video sample entry, with `st3d` mono) and
// the V1 XML `uuid` box (ffcc8263-f855-4a93-8814-587a02521fdd) in the video `trak`, so that
// players and sites show the file as an equirectangular 360-degree video.
//
// The file is edited in place when `moov` follows the media data (GStreamer's mp4mux default:
// no chunk offset changes); with `moov` first (faststart) the file is rewritten through a
// temporary file and every `stco`/`co64` chunk offset shifts by the bytes inserted.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

namespace stitch {

struct SphericalMetadata {
  // Cubemap (issue 15): V2 `cbmp` layout 0 (3 x 2 faces: right left up / down front back, as a
  // "cubemap" rig's canvas) instead of `equi`. V1 knows equirectangular only: no V1 box then.
  enum class Projection { Equirectangular, Cubemap };
  Projection projection = Projection::Equirectangular;
  bool v1 = true;  // the XML uuid box
  bool v2 = true;  // sv3d + st3d
  std::string software = "gst-stitch";
  int source_width = 0, source_height = 0;  // the full panorama (V1 FullPano*); 0: unknown
};

// Empty on success, else why the file was left unchanged.
std::string add_spherical_metadata(const std::string& path, const SphericalMetadata& meta);

// A box of an MP4 file (for tests and tools): type, offset of its header, total size, depth.
struct Mp4Box {
  std::string type;
  uint64_t offset = 0, size = 0;
  int depth = 0;
};
// Every box down the containers we know (moov, trak, mdia, minf, stbl, stsd entries, sv3d,
// proj); throws std::runtime_error on a malformed file.
std::vector<Mp4Box> list_mp4_boxes(const std::string& path);

}  // namespace stitch
