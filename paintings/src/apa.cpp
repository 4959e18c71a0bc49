// .apa version 1, all little-endian:
//   string  = u8 length, bytes (Latin-1)
//   header  = string "apainter", u16 version (1), u8 brush count, that many strings,
//             u32 stroke count
//   stroke  = u8 brush index, 3 x f32 colour RGB, f32 size (metres), u32 point count
//   point   = 3 x f32 position, 4 x f32 orientation quaternion, f32 pressure, u32 time (ms)
// The file ends exactly after the last point.
#include "deepcanvas/paintings/apa.hpp"

#include <algorithm>
#include <bit>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>

namespace deepcanvas::paintings {

using protocol::BrushMode;
using protocol::Stroke;
using protocol::StrokeSample;

namespace {

class Cursor {
 public:
  explicit Cursor(std::span<const std::uint8_t> b) : b_(b) {}
  std::size_t offset() const { return off_; }
  std::size_t remaining() const { return b_.size() - off_; }

  // Each reader names what it was reading so a truncation message says where and what.
  Result<std::uint8_t> u8(const char* what) {
    if (remaining() < 1) return truncated(what, 1);
    return b_[off_++];
  }
  Result<std::uint16_t> u16(const char* what) {
    if (remaining() < 2) return truncated(what, 2);
    const std::uint16_t v = static_cast<std::uint16_t>(b_[off_] | (b_[off_ + 1] << 8));
    off_ += 2;
    return v;
  }
  Result<std::uint32_t> u32(const char* what) {
    if (remaining() < 4) return truncated(what, 4);
    const std::uint32_t v = static_cast<std::uint32_t>(b_[off_]) |
                            (static_cast<std::uint32_t>(b_[off_ + 1]) << 8) |
                            (static_cast<std::uint32_t>(b_[off_ + 2]) << 16) |
                            (static_cast<std::uint32_t>(b_[off_ + 3]) << 24);
    off_ += 4;
    return v;
  }
  Result<float> f32(const char* what) {
    auto u = u32(what);
    if (!u) return std::move(u).error();
    return std::bit_cast<float>(*u);
  }
  Result<std::string> str(const char* what) {
    auto n = u8(what);
    if (!n) return std::move(n).error();
    if (remaining() < *n) return truncated(what, *n);
    std::string s(reinterpret_cast<const char*>(b_.data() + off_), *n);
    off_ += *n;
    return s;
  }

 private:
  Error truncated(const char* what, std::size_t need) const {
    return make_error(Errc::malformed, "offset " + std::to_string(off_) + ": truncated reading " +
                                           what + " (need " + std::to_string(need) + " bytes, " +
                                           std::to_string(remaining()) + " left)");
  }
  std::span<const std::uint8_t> b_;
  std::size_t off_ = 0;
};

Error bad_at(std::size_t off, const std::string& what) {
  return make_error(Errc::malformed, "offset " + std::to_string(off) + ": " + what);
}

// The file starts with the string "apainter": its length byte 8, then the eight letters.
constexpr std::uint8_t kMagic[9] = {8, 'a', 'p', 'a', 'i', 'n', 't', 'e', 'r'};
constexpr const char* kNotApa =
    "not an A-Painter .apa file (it does not start with the 'apainter' magic)";

// False when the bytes cannot be the start of a painting: a file shorter than the magic that
// agrees with it so far is a truncated painting, not another kind of file.
bool starts_like_apa(std::span<const std::uint8_t> bytes) {
  const std::size_t n = std::min(bytes.size(), sizeof kMagic);
  return n == 0 || std::memcmp(bytes.data(), kMagic, n) == 0;
}

#define APA_TRY(var, expr)                         \
  auto var##_r = (expr);                           \
  if (!var##_r) return std::move(var##_r).error(); \
  auto var = *var##_r

}  // namespace

Result<ApaPainting> parse_apa(std::span<const std::uint8_t> bytes, const ApaTransform& tf) {
  if (!std::isfinite(tf.scale) || tf.scale <= 0 || !std::isfinite(tf.offset[0]) ||
      !std::isfinite(tf.offset[1]) || !std::isfinite(tf.offset[2]))
    return make_error(Errc::invalid_argument,
                      "transform: scale must be finite and > 0, "
                      "offset finite");
  if (!starts_like_apa(bytes)) return bad_at(0, kNotApa);
  Cursor c(bytes);
  ApaPainting out;
  // What is there agrees with the magic (checked above): this fails only on a truncation.
  if (auto magic = c.str("magic"); !magic) return std::move(magic).error();
  const std::size_t version_off = c.offset();
  APA_TRY(version, c.u16("version"));
  if (version != 1)
    return make_error(Errc::unsupported, "offset " + std::to_string(version_off) +
                                             ": unsupported version " + std::to_string(version) +
                                             " (this reader speaks version 1)");
  APA_TRY(brush_count, c.u8("brush count"));
  for (unsigned i = 0; i < brush_count; ++i) {
    APA_TRY(name, c.str("brush name"));
    out.brush_names.push_back(std::move(name));
  }
  const std::size_t count_off = c.offset();
  APA_TRY(stroke_count, c.u32("stroke count"));
  // Each stroke takes at least 21 bytes: refuse counts the file cannot hold before allocating.
  if (stroke_count > c.remaining() / 21)
    return bad_at(count_off, "stroke count " + std::to_string(stroke_count) +
                                 " does not fit in the " + std::to_string(c.remaining()) +
                                 " bytes that follow (truncated or corrupt)");
  out.strokes.reserve(stroke_count);
  for (std::uint32_t s = 0; s < stroke_count; ++s) {
    const std::string at = "stroke " + std::to_string(s) + ": ";
    const std::size_t brush_off = c.offset();
    APA_TRY(brush, c.u8("stroke brush index"));
    if (brush >= brush_count)
      return bad_at(brush_off, at + "brush index " + std::to_string(brush) + " out of range (" +
                                   std::to_string(brush_count) + " brushes)");
    Stroke st;
    st.brush.mode = BrushMode::paint;
    st.brush.opacity = 1.0f;
    for (int k = 0; k < 3; ++k) {
      const std::size_t off = c.offset();
      APA_TRY(v, c.f32("stroke colour"));
      if (!std::isfinite(v) || v < 0.0f || v > 1.0f)
        return bad_at(off, at + "colour channel not a number in 0..1");
      st.brush.colour[k] = v;
    }
    st.brush.colour[3] = 1.0f;
    const std::size_t size_off = c.offset();
    APA_TRY(size, c.f32("stroke size"));
    if (!std::isfinite(size) || size <= 0.0f)
      return bad_at(size_off, at + "brush size not a finite number > 0");
    const std::size_t np_off = c.offset();
    APA_TRY(points, c.u32("stroke point count"));
    if (points > c.remaining() / 36)
      return bad_at(np_off, at + "point count " + std::to_string(points) +
                                " does not fit in the bytes that follow (truncated or corrupt)");
    st.samples.reserve(points);
    for (std::uint32_t p = 0; p < points; ++p) {
      const std::size_t point_off = c.offset();
      float v[8];
      for (int k = 0; k < 8; ++k) {
        APA_TRY(x, c.f32(k < 3   ? "point position"
                         : k < 7 ? "point orientation"
                                 : "point pressure"));
        if (!std::isfinite(x))
          return bad_at(c.offset() - 4, at + "point " + std::to_string(p) + ": " +
                                            (k < 3   ? "position"
                                             : k < 7 ? "orientation"
                                                     : "pressure") +
                                            " is not a finite number");
        v[k] = x;
      }
      if (v[7] < 0.0f)
        return bad_at(point_off + 28, at + "point " + std::to_string(p) + ": negative pressure " +
                                          std::to_string(v[7]));
      APA_TRY(t, c.u32("point timestamp"));
      StrokeSample smp;
      smp.x = static_cast<double>(v[0]) * tf.scale + tf.offset[0];
      smp.y = static_cast<double>(v[1]) * tf.scale + tf.offset[1];
      smp.z = static_cast<double>(v[2]) * tf.scale + tf.offset[2];
      smp.radius = static_cast<float>(static_cast<double>(size) * 0.5 * tf.scale);
      smp.pressure = std::clamp(v[7], kApaMinPressure, 1.0f);
      smp.t_ms = t;
      st.samples.push_back(smp);
    }
    out.sample_count += points;
    out.stroke_brush.push_back(brush);
    out.strokes.push_back(std::move(st));
  }
  if (c.remaining() != 0)
    return bad_at(c.offset(),
                  std::to_string(c.remaining()) + " trailing bytes after the last stroke");
  return out;
}

Result<std::vector<std::uint8_t>> read_file_bytes(const std::string& path,
                                                  std::uint64_t max_bytes) {
  std::FILE* f = std::fopen(path.c_str(), "rb");
  if (!f)
    return make_error(errno == ENOENT ? Errc::not_found : Errc::io_error,
                      path + ": cannot open: " + std::strerror(errno));
  std::vector<std::uint8_t> bytes;
  std::uint8_t buf[1 << 16];
  for (;;) {
    const std::size_t n = std::fread(buf, 1, sizeof buf, f);
    if (n == 0) break;
    if (bytes.size() + n > max_bytes) {
      std::fclose(f);
      return make_error(Errc::limit_exceeded,
                        path + ": larger than " + std::to_string(max_bytes) + " bytes");
    }
    bytes.insert(bytes.end(), buf, buf + n);
  }
  const bool err = std::ferror(f) != 0;
  std::fclose(f);
  if (err) return make_error(Errc::io_error, path + ": read error");
  return bytes;
}

Result<ApaPainting> read_apa_file(const std::string& path, const ApaTransform& transform) {
  auto bytes = read_file_bytes(path);
  if (!bytes) return std::move(bytes).error();
  if (!starts_like_apa(*bytes)) return make_error(Errc::malformed, path + " is " + kNotApa);
  auto p = parse_apa(*bytes, transform);
  if (!p) {
    Error e = std::move(p).error();
    e.message = path + ": " + e.message;
    return e;
  }
  return p;
}

}  // namespace deepcanvas::paintings
