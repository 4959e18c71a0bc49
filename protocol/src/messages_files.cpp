// The messages that carry files: import (PROTOCOL.md 3.11), export (3.12), and the base64 the
// files travel in.
#include <array>

#include "json_fields.hpp"

namespace deepcanvas::protocol::detail {

namespace {

constexpr char kAlphabet[] = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";

int sextet(char c) {
  if (c >= 'A' && c <= 'Z') return c - 'A';
  if (c >= 'a' && c <= 'z') return c - 'a' + 26;
  if (c >= '0' && c <= '9') return c - '0' + 52;
  if (c == '+') return 62;
  if (c == '/') return 63;
  return -1;
}

}  // namespace

std::string base64_encode(std::span<const std::uint8_t> b) {
  std::string out;
  out.reserve((b.size() + 2) / 3 * 4);
  std::size_t i = 0;
  for (; i + 3 <= b.size(); i += 3) {
    const std::uint32_t v = (std::uint32_t{b[i]} << 16) | (std::uint32_t{b[i + 1]} << 8) | b[i + 2];
    for (int k = 3; k >= 0; --k) out.push_back(kAlphabet[(v >> (6 * k)) & 63]);
  }
  if (i < b.size()) {
    std::uint32_t v = std::uint32_t{b[i]} << 16;
    if (i + 1 < b.size()) v |= std::uint32_t{b[i + 1]} << 8;
    out.push_back(kAlphabet[(v >> 18) & 63]);
    out.push_back(kAlphabet[(v >> 12) & 63]);
    out.push_back(i + 1 < b.size() ? kAlphabet[(v >> 6) & 63] : '=');
    out.push_back('=');
  }
  return out;
}

Result<std::vector<std::uint8_t>> base64_decode(std::string_view t) {
  if (t.size() % 4 != 0) return malformed("base64: length not a multiple of 4");
  std::vector<std::uint8_t> out;
  out.reserve(t.size() / 4 * 3);
  for (std::size_t i = 0; i < t.size(); i += 4) {
    const bool last = i + 4 == t.size();
    const int pad = last ? (t[i + 3] == '=') + (t[i + 2] == '=') : 0;
    if (pad == 1 && t[i + 2] == '=') return malformed("base64: bad padding");
    std::uint32_t v = 0;
    for (int k = 0; k < 4 - pad; ++k) {
      const int s = sextet(t[i + static_cast<std::size_t>(k)]);
      if (s < 0) return malformed("base64: a character outside the alphabet");
      v |= static_cast<std::uint32_t>(s) << (6 * (3 - k));
    }
    out.push_back(static_cast<std::uint8_t>(v >> 16));
    if (pad < 2) out.push_back(static_cast<std::uint8_t>(v >> 8));
    if (pad < 1) out.push_back(static_cast<std::uint8_t>(v));
  }
  return out;
}

json import_json(const Import& m) {
  return {{"type", "import"},
          {"request_id", m.request_id},
          {"format", m.format},
          {"at", {m.at[0], m.at[1], m.at[2]}},
          {"scale", m.scale},
          {"voxel_size_m", m.voxel_size_m},
          {"colour", {m.colour[0], m.colour[1], m.colour[2]}},
          {"density_scale", m.density_scale},
          {"data", base64_encode(m.data)}};
}

json import_reply_json(const ImportReply& m) {
  return {{"type", "import_reply"},
          {"request_id", m.request_id},
          {"stroke_id", m.stroke_id},
          {"epoch", m.epoch},
          {"cells", m.cells}};
}

Result<Message> read_import(const Obj& o, const DecodeOptions& opt, MessageRef* about) {
  Import m;
  DC_TRY(id, o.uint("request_id"));
  m.request_id = id;
  if (about) about->handle = id;
  DC_TRY(format, o.string("format", 8));
  if (format != "vdb" && format != "gltf" && format != "glb" && format != "ply")
    return out_of_range("field 'format' must be vdb, gltf, glb or ply");
  m.format = format;
  DC_TRY(at, o.array("at"));
  if (at->size() != 3) return malformed("field 'at' must hold 3 numbers");
  const double half = opt.bounds.edge_m * 0.5;
  for (std::size_t i = 0; i < 3; ++i) {
    DC_TRY(v, Obj::number_value((*at)[i], "at[" + std::to_string(i) + "]", -half, half));
    m.at[i] = v;
  }
  DC_TRY(scale, o.number("scale", 0, 1e9));
  if (!(scale > 0)) return out_of_range("field 'scale' must be positive");
  m.scale = scale;
  DC_TRY(voxel, o.number("voxel_size_m", 0, opt.bounds.edge_m));
  m.voxel_size_m = voxel;
  DC_TRY(colour, o.array("colour"));
  if (colour->size() != 3) return malformed("field 'colour' must hold 3 numbers");
  for (std::size_t i = 0; i < 3; ++i) {
    DC_TRY(v, Obj::number_value((*colour)[i], "colour[" + std::to_string(i) + "]", 0, 1));
    m.colour[i] = static_cast<float>(v);
  }
  DC_TRY(density, o.number("density_scale", 0, 1e9));
  if (!(density > 0)) return out_of_range("field 'density_scale' must be positive");
  m.density_scale = density;
  DC_TRY(data, o.string("data", opt.max_bytes));
  if (data.empty()) return malformed("field 'data' is empty: no file");
  auto bytes = base64_decode(data);
  if (!bytes) return malformed("field 'data': " + bytes.error().message);
  m.data = std::move(*bytes);
  return Message(std::move(m));
}

Result<Message> read_import_reply(const Obj& o, MessageRef* about) {
  ImportReply m;
  DC_TRY(id, o.uint("request_id"));
  if (about) about->handle = id;
  DC_TRY(stroke, o.uint("stroke_id"));
  DC_TRY(epoch, o.uint("epoch"));
  DC_TRY(cells, o.uint("cells"));
  m.request_id = id;
  m.stroke_id = stroke;
  m.epoch = epoch;
  m.cells = cells;
  return Message(m);
}

namespace {
bool known_format(const std::string& f) {
  return f == "vdb" || f == "gltf" || f == "glb" || f == "ply";
}
}  // namespace

json export_json(const ExportRequest& m) {
  json j = {{"type", "export"},
            {"request_id", m.request_id},
            {"format", m.format},
            {"voxel_size_m", m.voxel_size_m},
            {"max_bytes", m.max_bytes}};
  if (m.box) j["box"] = *m.box;
  return j;
}

json export_reply_json(const ExportReply& m) {
  return {{"type", "export_reply"},
          {"request_id", m.request_id},
          {"format", m.format},
          {"data", base64_encode(m.data)}};
}

Result<Message> read_export(const Obj& o, const DecodeOptions& opt, MessageRef* about) {
  ExportRequest m;
  DC_TRY(id, o.uint("request_id"));
  m.request_id = id;
  if (about) about->handle = id;
  DC_TRY(format, o.string("format", 8));
  if (!known_format(format)) return out_of_range("field 'format' must be vdb, gltf, glb or ply");
  m.format = format;
  DC_TRY(voxel, o.number("voxel_size_m", 0, opt.bounds.edge_m));
  m.voxel_size_m = voxel;
  DC_TRY(max_bytes, o.uint("max_bytes"));
  m.max_bytes = max_bytes;
  if (o.has("box")) {
    DC_TRY(box, read_box(o, "box", opt.bounds.edge_m));
    m.box = box;
  }
  return Message(std::move(m));
}

Result<Message> read_export_reply(const Obj& o, const DecodeOptions& opt, MessageRef* about) {
  ExportReply m;
  DC_TRY(id, o.uint("request_id"));
  m.request_id = id;
  if (about) about->handle = id;
  DC_TRY(format, o.string("format", 8));
  if (!known_format(format)) return out_of_range("field 'format' must be vdb, gltf, glb or ply");
  m.format = format;
  DC_TRY(data, o.string("data", opt.max_bytes));
  auto bytes = base64_decode(data);
  if (!bytes) return malformed("field 'data': " + bytes.error().message);
  m.data = std::move(*bytes);
  return Message(std::move(m));
}

}  // namespace deepcanvas::protocol::detail
