#include "stitch/io/spherical_mp4.hpp"

#include <cstdio>
#include <cstring>
#include <functional>
#include <iterator>
#include <fstream>
#include <stdexcept>

namespace stitch {
namespace {

uint32_t rd32(const uint8_t* p) { return uint32_t(p[0]) << 24 | uint32_t(p[1]) << 16 | uint32_t(p[2]) << 8 | p[3]; }
uint64_t rd64(const uint8_t* p) { return uint64_t(rd32(p)) << 32 | rd32(p + 4); }
void wr32(uint8_t* p, uint32_t v) {
  p[0] = uint8_t(v >> 24), p[1] = uint8_t(v >> 16), p[2] = uint8_t(v >> 8), p[3] = uint8_t(v);
}
void wr64(uint8_t* p, uint64_t v) {
  wr32(p, uint32_t(v >> 32));
  wr32(p + 4, uint32_t(v));
}
void put32(std::vector<uint8_t>& b, uint32_t v) {
  const size_t n = b.size();
  b.resize(n + 4);
  wr32(b.data() + n, v);
}
void put_type(std::vector<uint8_t>& b, const char* t) { b.insert(b.end(), t, t + 4); }

std::vector<uint8_t> box(const char* type, const std::vector<uint8_t>& payload) {
  std::vector<uint8_t> b;
  put32(b, uint32_t(8 + payload.size()));
  put_type(b, type);
  b.insert(b.end(), payload.begin(), payload.end());
  return b;
}

std::vector<uint8_t> full_box(const char* type, const std::vector<uint8_t>& payload) {
  std::vector<uint8_t> p = {0, 0, 0, 0};  // version 0, flags 0
  p.insert(p.end(), payload.begin(), payload.end());
  return box(type, p);
}

std::vector<uint8_t> v2_boxes(const SphericalMetadata& m) {
  std::vector<uint8_t> svhd_payload(m.software.begin(), m.software.end());
  svhd_payload.push_back(0);
  std::vector<uint8_t> prhd_payload(12, 0);  // pose yaw, pitch, roll = 0 (16.16 fixed)
  std::vector<uint8_t> equi_payload(16, 0);  // no crop: bounds top, bottom, left, right = 0
  std::vector<uint8_t> cbmp_payload(8, 0);   // layout 0 (3 x 2), padding 0
  std::vector<uint8_t> proj_payload = full_box("prhd", prhd_payload);
  const auto equi = m.projection == SphericalMetadata::Projection::Cubemap ? full_box("cbmp", cbmp_payload)
                                                                           : full_box("equi", equi_payload);
  proj_payload.insert(proj_payload.end(), equi.begin(), equi.end());
  std::vector<uint8_t> sv3d_payload = full_box("svhd", svhd_payload);
  const auto proj = box("proj", proj_payload);
  sv3d_payload.insert(sv3d_payload.end(), proj.begin(), proj.end());
  std::vector<uint8_t> out = full_box("st3d", {0});  // stereo mode 0: monoscopic
  const auto sv3d = box("sv3d", sv3d_payload);
  out.insert(out.end(), sv3d.begin(), sv3d.end());
  return out;
}

std::vector<uint8_t> v1_box(const SphericalMetadata& m) {
  static const uint8_t kUuid[16] = {0xff, 0xcc, 0x82, 0x63, 0xf8, 0x55, 0x4a, 0x93,
                                    0x88, 0x14, 0x58, 0x7a, 0x02, 0x52, 0x1f, 0xdd};
  std::string xml =
      "<?xml version=\"1.0\"?><rdf:SphericalVideo\n"
      "xmlns:rdf=\"http://www.w3.org/1999/02/22-rdf-syntax-ns#\"\n"
      "xmlns:GSpherical=\"http://ns.google.com/videos/1.0/spherical/\">"
      "<GSpherical:Spherical>true</GSpherical:Spherical>"
      "<GSpherical:Stitched>true</GSpherical:Stitched>"
      "<GSpherical:StitchingSoftware>" + m.software + "</GSpherical:StitchingSoftware>"
      "<GSpherical:ProjectionType>equirectangular</GSpherical:ProjectionType>";
  if (m.source_width > 0 && m.source_height > 0) {
    const std::string w = std::to_string(m.source_width), h = std::to_string(m.source_height);
    xml += "<GSpherical:CroppedAreaImageWidthPixels>" + w + "</GSpherical:CroppedAreaImageWidthPixels>"
           "<GSpherical:CroppedAreaImageHeightPixels>" + h + "</GSpherical:CroppedAreaImageHeightPixels>"
           "<GSpherical:FullPanoWidthPixels>" + w + "</GSpherical:FullPanoWidthPixels>"
           "<GSpherical:FullPanoHeightPixels>" + h + "</GSpherical:FullPanoHeightPixels>"
           "<GSpherical:CroppedAreaLeftPixels>0</GSpherical:CroppedAreaLeftPixels>"
           "<GSpherical:CroppedAreaTopPixels>0</GSpherical:CroppedAreaTopPixels>";
  }
  xml += "</rdf:SphericalVideo>";
  std::vector<uint8_t> payload(kUuid, kUuid + 16);
  payload.insert(payload.end(), xml.begin(), xml.end());
  return box("uuid", payload);
}

struct Header {
  uint64_t size = 0;  // total
  uint32_t header = 8;
  char type[5] = {0};
};

// Header of the box at `p` (within `end`); false when malformed.
bool header_at(const uint8_t* p, const uint8_t* end, Header& h) {
  if (end - p < 8) return false;
  h.size = rd32(p);
  std::memcpy(h.type, p + 4, 4);
  h.header = 8;
  if (h.size == 1) {
    if (end - p < 16) return false;
    h.size = rd64(p + 8);
    h.header = 16;
  } else if (h.size == 0) {
    h.size = uint64_t(end - p);
  }
  return h.size >= h.header && h.size <= uint64_t(end - p);
}

bool is(const Header& h, const char* t) { return std::memcmp(h.type, t, 4) == 0; }

// Offset of the first child box of a container of type `t` (relative to the box start).
uint32_t children_offset(const Header& h) {
  if (is(h, "stsd")) return h.header + 8;  // full box + entry count
  if (is(h, "avc1") || is(h, "avc3") || is(h, "hvc1") || is(h, "hev1") || is(h, "mp4v") || is(h, "vp09") ||
      is(h, "av01"))
    return h.header + 78;  // VisualSampleEntry
  return h.header;
}

bool is_container(const Header& h) {
  static const char* kContainers[] = {"moov", "trak", "mdia", "minf", "stbl", "stsd", "avc1", "avc3", "hvc1",
                                      "hev1", "mp4v", "vp09", "av01", "sv3d", "proj", "edts", "dinf"};
  for (const char* c : kContainers)
    if (is(h, c)) return true;
  return false;
}

// The moov box's bytes edited: returns the new moov, or an error.
// shift_offsets: the media follows moov, so every chunk offset moves by the bytes inserted.
std::string edit_moov(std::vector<uint8_t>& moov, const SphericalMetadata& meta, bool shift_offsets) {
  const uint8_t* base = moov.data();
  const uint8_t* end = base + moov.size();
  Header mh;
  if (!header_at(base, end, mh) || mh.header != 8) return "malformed moov";
  // Find the video trak: its mdia/hdlr says 'vide'.
  struct Path {
    size_t trak = 0, mdia = 0, minf = 0, stbl = 0, stsd = 0, entry = 0;
  };
  bool found = false;
  Path path;
  for (const uint8_t* p = base + 8; p < end;) {
    Header h;
    if (!header_at(p, end, h)) return "malformed box in moov";
    if (is(h, "trak")) {
      Path cand;
      cand.trak = size_t(p - base);
      bool video = false;
      for (const uint8_t* q = p + 8; q < p + h.size;) {
        Header a;
        if (!header_at(q, p + h.size, a)) return "malformed trak";
        if (is(a, "mdia")) {
          cand.mdia = size_t(q - base);
          for (const uint8_t* r = q + 8; r < q + a.size;) {
            Header b;
            if (!header_at(r, q + a.size, b)) return "malformed mdia";
            if (is(b, "hdlr") && b.size >= 20 && std::memcmp(r + 16, "vide", 4) == 0) video = true;
            if (is(b, "minf")) {
              cand.minf = size_t(r - base);
              for (const uint8_t* s = r + 8; s < r + b.size;) {
                Header c;
                if (!header_at(s, r + b.size, c)) return "malformed minf";
                if (is(c, "stbl")) {
                  cand.stbl = size_t(s - base);
                  for (const uint8_t* t = s + 8; t < s + c.size;) {
                    Header d;
                    if (!header_at(t, s + c.size, d)) return "malformed stbl";
                    if (is(d, "stsd") && d.size >= 24) {
                      cand.stsd = size_t(t - base);
                      cand.entry = cand.stsd + 16;
                    }
                    t += d.size;
                  }
                }
                s += c.size;
              }
            }
            r += b.size;
          }
        }
        q += a.size;
      }
      if (video && cand.entry) {
        path = cand;
        found = true;
        break;
      }
    }
    p += h.size;
  }
  if (!found) return "no video track with a sample description";
  Header entry;
  if (!header_at(base + path.entry, end, entry) || entry.header != 8) return "malformed sample entry";
  // Already spherical? Leave it.
  for (const uint8_t* q = base + path.entry + children_offset(entry); q + 8 <= base + path.entry + entry.size;) {
    Header h;
    if (!header_at(q, base + path.entry + entry.size, h)) break;
    if (is(h, "sv3d")) return {};
    q += h.size;
  }
  const std::vector<uint8_t> v2 = meta.v2 ? v2_boxes(meta) : std::vector<uint8_t>();
  const bool v1_fits = meta.projection == SphericalMetadata::Projection::Equirectangular;
  const std::vector<uint8_t> v1 = meta.v1 && v1_fits ? v1_box(meta) : std::vector<uint8_t>();
  // Insert V2 at the end of the sample entry, V1 at the end of the trak (later first, so the
  // earlier offsets stay valid).
  const size_t trak_end = path.trak + rd32(base + path.trak);
  const size_t entry_end = path.entry + entry.size;
  moov.insert(moov.begin() + long(trak_end), v1.begin(), v1.end());
  moov.insert(moov.begin() + long(entry_end), v2.begin(), v2.end());
  auto grow = [&](size_t at, size_t by) { wr32(moov.data() + at, uint32_t(rd32(moov.data() + at) + by)); };
  const size_t both = v1.size() + v2.size();
  grow(0, both);
  grow(path.trak, both);
  for (size_t at : {path.mdia, path.minf, path.stbl, path.stsd, path.entry}) grow(at, v2.size());
  // Chunk offsets (moov before the media data: everything after it moved).
  if (shift_offsets) {
    const int64_t shift = int64_t(both);
    std::function<std::string(size_t, size_t)> fix = [&](size_t from, size_t to) -> std::string {
      for (size_t p = from; p + 8 <= to;) {
        Header h;
        if (!header_at(moov.data() + p, moov.data() + to, h)) return "malformed box while fixing offsets";
        if (is(h, "stco") || is(h, "co64")) {
          const uint32_t n = rd32(moov.data() + p + 12);
          const size_t w = is(h, "stco") ? 4 : 8;
          if (16 + uint64_t(n) * w > h.size) return "malformed chunk offset table";
          for (uint32_t k = 0; k < n; ++k) {
            uint8_t* e = moov.data() + p + 16 + k * w;
            if (w == 4) {
              const int64_t v = int64_t(rd32(e)) + shift;
              if (v > 0xffffffffLL) return "chunk offsets overflow 32 bits";
              wr32(e, uint32_t(v));
            } else {
              wr64(e, uint64_t(int64_t(rd64(e)) + shift));
            }
          }
        } else if (is_container(h) && !is(h, "stsd")) {
          const std::string e = fix(p + children_offset(h), p + h.size);
          if (!e.empty()) return e;
        }
        p += h.size;
      }
      return {};
    };
    const std::string e = fix(8, moov.size());
    if (!e.empty()) return e;
  }
  return {};
}

}  // namespace

std::string add_spherical_metadata(const std::string& path, const SphericalMetadata& meta) {
  std::FILE* f = std::fopen(path.c_str(), "r+b");
  if (!f) return "cannot open \"" + path + "\" for update";
  struct Closer {
    std::FILE* f;
    ~Closer() {
      if (f) std::fclose(f);
    }
  } closer{f};
  // Top-level boxes.
  uint64_t pos = 0, moov_at = 0, moov_size = 0;
  bool media_after_moov = false, have_moov = false;
  std::fseek(f, 0, SEEK_END);
  const uint64_t file_size = uint64_t(std::ftell(f));
  while (pos + 8 <= file_size) {
    uint8_t hb[16];
    std::fseek(f, long(pos), SEEK_SET);
    if (std::fread(hb, 1, 8, f) != 8) return "short read";
    uint64_t size = rd32(hb);
    if (size == 1) {
      if (std::fread(hb + 8, 1, 8, f) != 8) return "short read";
      size = rd64(hb + 8);
    } else if (size == 0) {
      size = file_size - pos;
    }
    if (size < 8 || pos + size > file_size) return "malformed top-level box";
    if (std::memcmp(hb + 4, "moov", 4) == 0) moov_at = pos, moov_size = size, have_moov = true;
    if (std::memcmp(hb + 4, "mdat", 4) == 0 && have_moov) media_after_moov = true;
    pos += size;
  }
  if (!have_moov) return "no moov box (not an MP4 file, or not finished)";
  std::vector<uint8_t> moov(moov_size);
  std::fseek(f, long(moov_at), SEEK_SET);
  if (std::fread(moov.data(), 1, moov.size(), f) != moov.size()) return "short read";
  const size_t old_size = moov.size();
  const std::string e = edit_moov(moov, meta, media_after_moov);
  if (!e.empty()) return e;
  if (moov.size() == old_size) return {};  // already spherical
  if (!media_after_moov) {
    // moov is last (after the media): rewrite it in place, the file grows.
    std::fseek(f, long(moov_at), SEEK_SET);
    if (std::fwrite(moov.data(), 1, moov.size(), f) != moov.size()) return "write failed";
    return {};
  }
  // moov first (faststart): write the file anew with the grown moov, then replace it.
  const std::string tmp = path + ".sv.tmp";
  std::FILE* o = std::fopen(tmp.c_str(), "wb");
  if (!o) return "cannot write \"" + tmp + "\"";
  std::vector<uint8_t> buf(1 << 20);
  auto copy = [&](uint64_t from, uint64_t n) {
    std::fseek(f, long(from), SEEK_SET);
    while (n > 0) {
      const size_t k = size_t(std::min<uint64_t>(n, buf.size()));
      if (std::fread(buf.data(), 1, k, f) != k || std::fwrite(buf.data(), 1, k, o) != k) return false;
      n -= k;
    }
    return true;
  };
  bool ok = copy(0, moov_at) && std::fwrite(moov.data(), 1, moov.size(), o) == moov.size() &&
            copy(moov_at + old_size, file_size - moov_at - old_size);
  ok &= std::fclose(o) == 0;
  if (!ok || std::rename(tmp.c_str(), path.c_str()) != 0) {
    std::remove(tmp.c_str());
    return "cannot rewrite \"" + path + "\"";
  }
  return {};
}

std::vector<Mp4Box> list_mp4_boxes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw std::runtime_error("cannot open " + path);
  std::vector<uint8_t> data((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  std::vector<Mp4Box> out;
  std::function<void(size_t, size_t, int)> walk = [&](size_t from, size_t to, int depth) {
    for (size_t p = from; p + 8 <= to;) {
      Header h;
      if (!header_at(data.data() + p, data.data() + to, h)) throw std::runtime_error("malformed box");
      out.push_back({std::string(h.type, 4), p, h.size, depth});
      if (is_container(h) && !is(h, "mdat")) walk(p + children_offset(h), p + h.size, depth + 1);
      p += h.size;
    }
  };
  walk(0, data.size(), 0);
  return out;
}

}  // namespace stitch
