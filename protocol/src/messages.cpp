#include "deepcanvas/protocol/messages.hpp"

#include <array>
#include <cmath>
#include <limits>
#include <nlohmann/json.hpp>
#include <span>
#include <string>
#include <type_traits>

#include "json_fields.hpp"

namespace deepcanvas::protocol {

using nlohmann::json;

namespace {

using detail::malformed;
using detail::Obj;
using detail::out_of_range;

constexpr Errc kAllErrc[] = {Errc::ok,          Errc::invalid_argument, Errc::malformed,
                             Errc::unsupported, Errc::out_of_memory,    Errc::refused,
                             Errc::not_found,   Errc::limit_exceeded,   Errc::unauthorized,
                             Errc::io_error,    Errc::internal};

// ---- brush and samples ----

json brush_json(const Brush& b) {
  return json{{"mode", brush_mode_name(b.mode)},
              {"colour", {b.colour[0], b.colour[1], b.colour[2], b.colour[3]}},
              {"opacity", b.opacity},
              {"hardness", b.hardness}};
}

json samples_json(std::span<const StrokeSample> samples) {
  json a = json::array();
  for (const auto& s : samples) a.push_back({s.x, s.y, s.z, s.radius, s.pressure, s.t_ms});
  return a;
}

constexpr double kFloatMax = std::numeric_limits<float>::max();

// The JSON readers below check only that each value has the right JSON type and fits its C++
// type; the ranges are the stroke rules' (ValidatedBrush / ValidatedSamples, stroke.cpp).
Result<ValidatedBrush> read_brush(const Obj& o) {
  Brush b;
  DC_TRY(mode_name, o.string("mode", 32));
  DC_TRY(mode, parse_brush_mode(mode_name));
  b.mode = mode;
  DC_TRY(colour, o.array("colour"));
  if (colour->size() != 4) return malformed("field '" + o.name("colour") + "' must hold 4 numbers");
  for (int c = 0; c < 4; ++c) {
    DC_TRY(v, Obj::number_value((*colour)[static_cast<std::size_t>(c)],
                                o.name("colour") + "[" + std::to_string(c) + "]", -kFloatMax,
                                kFloatMax));
    b.colour[c] = static_cast<float>(v);
  }
  DC_TRY(opacity, o.number("opacity", -kFloatMax, kFloatMax));
  DC_TRY(hardness, o.number("hardness", -kFloatMax, kFloatMax));
  b.opacity = static_cast<float>(opacity);
  b.hardness = static_cast<float>(hardness);
  return ValidatedBrush::make(b);
}

// Samples as [x, y, z, radius, pressure, t_ms]: each entry a finite number that fits its C++
// type (floats: within float range), then ValidatedSamples::make applies the stroke rules. The
// count is checked first, so that an oversized array is refused before it is read.
Result<ValidatedSamples> read_samples(const Obj& o, bool allow_empty, const DecodeOptions& opt) {
  DC_TRY(arr, o.array("samples"));
  if (arr->empty() && !allow_empty) return out_of_range("field 'samples' must not be empty");
  if (auto n = check_sample_count(arr->size(), opt.stroke_limits); !n) return std::move(n).error();
  std::vector<StrokeSample> out;
  out.reserve(arr->size());
  for (std::size_t i = 0; i < arr->size(); ++i) {
    const json& e = (*arr)[i];
    const std::string at = "samples[" + std::to_string(i) + "]";
    if (!e.is_array() || e.size() != 6)
      return malformed("field '" + at + "' must be [x, y, z, radius, pressure, t_ms]");
    StrokeSample s;
    DC_TRY(x, Obj::number_value(e[0], at + "[0]", -1e300, 1e300));
    DC_TRY(y, Obj::number_value(e[1], at + "[1]", -1e300, 1e300));
    DC_TRY(z, Obj::number_value(e[2], at + "[2]", -1e300, 1e300));
    DC_TRY(r, Obj::number_value(e[3], at + "[3]", -kFloatMax, kFloatMax));
    DC_TRY(p, Obj::number_value(e[4], at + "[4]", -kFloatMax, kFloatMax));
    DC_TRY(t, Obj::uint_value(e[5], at + "[5]", std::numeric_limits<std::uint32_t>::max()));
    s.x = x;
    s.y = y;
    s.z = z;
    s.radius = static_cast<float>(r);
    s.pressure = static_cast<float>(p);
    s.t_ms = static_cast<std::uint32_t>(t);
    out.push_back(s);
  }
  return ValidatedSamples::make(std::move(out), StrokeRules{opt.bounds, opt.stroke_limits});
}

Result<std::uint64_t> read_handle(const Obj& o, MessageRef* about, const char* key = "handle") {
  auto h = o.uint(key);
  if (h && about) about->handle = *h;
  return h;
}

Result<Role> read_role(const Obj& o) {
  DC_TRY(name, o.string("role", 16));
  auto r = parse_role(name);
  if (!r) return out_of_range("field 'role': " + r.error().message);
  return r;
}

Result<std::string> read_canvas(const Obj& o) {
  DC_TRY(c, o.string("canvas", 64));
  if (!is_valid_canvas_name(c))
    return out_of_range("field 'canvas' must be 1..64 characters of [A-Za-z0-9._-]");
  return c;
}

Result<void> check_version(const Obj& o, std::string_view type) {
  auto v = o.uint("protocol_version", 0xFFFFFFFFu);
  if (!v) return std::move(v).error();
  if (*v != kProtocolVersion)
    return make_error(Errc::unsupported, std::string(type) + ": protocol version " +
                                             std::to_string(*v) +
                                             " is not supported (this side speaks " +
                                             std::to_string(kProtocolVersion) + ")");
  return {};
}

// ---- per-type decoders ----

Result<std::array<double, 3>> read_point(const Obj& o, std::string_view key, double limit);
// Camera coordinates and brush sizes: any finite value a renderer can square without overflow.
constexpr double kPresenceMaxMetres = 1e12;

Result<Message> read_hello(const Obj& o) {
  if (auto v = check_version(o, "hello"); !v) return std::move(v).error();
  Hello m;
  DC_TRY(role, read_role(o));
  DC_TRY(token, o.string("token", 256));
  if (!is_valid_token(token))
    return out_of_range("field 'token' must be 1..256 printable ASCII characters without spaces");
  DC_TRY(canvas, read_canvas(o));
  DC_TRY(client_name, o.string("client_name", 128));
  m.role = role;
  m.token = std::move(token);
  m.canvas = std::move(canvas);
  m.client_name = std::move(client_name);
  if (o.has("delta_frames")) {
    DC_TRY(delta, o.boolean("delta_frames"));
    m.delta_frames = delta;
  }
  if (o.has("frame_bundles")) {
    DC_TRY(bundles, o.boolean("frame_bundles"));
    m.frame_bundles = bundles;
  }
  if (o.has("block_frames")) {
    DC_TRY(frames, o.boolean("block_frames"));
    m.block_frames = frames;
  }
  if (o.has("client_id")) {
    DC_TRY(id, o.string("client_id", 64));
    if (!is_valid_client_id(id))
      return out_of_range("field 'client_id' must be 1..64 characters of [A-Za-z0-9_-]");
    m.client_id = std::move(id);
  }
  if (o.has("batch_interval_ms")) {
    DC_TRY(interval, o.uint("batch_interval_ms", kMaxBatchIntervalMs));
    m.batch_interval_ms = static_cast<std::uint32_t>(interval);
  }
  if (o.has("camera")) {
    DC_TRY(c, o.object("camera"));
    DC_TRY(eye, read_point(c, "eye", kPresenceMaxMetres));
    DC_TRY(target, read_point(c, "target", kPresenceMaxMetres));
    if (eye == target) return out_of_range("field 'camera.target' must differ from 'camera.eye'");
    m.camera = JoinCamera{eye, target};
  }
  return Message(std::move(m));
}

Result<Message> read_welcome(const Obj& o) {
  if (auto v = check_version(o, "welcome"); !v) return std::move(v).error();
  Welcome m;
  DC_TRY(role, read_role(o));
  DC_TRY(canvas, read_canvas(o));
  DC_TRY(g, o.object("geometry"));
  DC_TRY(rpa, g.uint("roots_per_axis", 64));
  if (rpa < 2 || rpa % 2)
    return out_of_range("field 'geometry.roots_per_axis' must be an even number in 2..64");
  DC_TRY(edge, g.number("edge_m", 0.0, 1e12));
  if (!(edge > 0)) return out_of_range("field 'geometry.edge_m' must be positive");
  DC_TRY(depth, g.uint("max_depth", 24));
  if (depth < 1) return out_of_range("field 'geometry.max_depth' must be in 1..24");
  DC_TRY(block_cells, o.uint("block_cells", 1u << 20));
  if (block_cells < 64 || (block_cells & (block_cells - 1)))
    return out_of_range("field 'block_cells' must be a power of two in 64..2^20");
  DC_TRY(tw, o.uint("texture_width", 1u << 16));
  if (tw < 1 || (tw & (tw - 1)))
    return out_of_range("field 'texture_width' must be a power of two in 1..65536");
  DC_TRY(epoch, o.uint("epoch"));
  DC_TRY(pl, o.object("pool_layout"));
  DC_TRY(pl_id, pl.string("id", 64));
  DC_TRY(pl_version, pl.uint("version", 0xFFFFFFFFu));
  DC_TRY(lim, o.object("limits"));
  DC_TRY(max_frame, lim.uint("max_frame_bytes"));
  DC_TRY(max_samples, lim.uint("max_samples_per_stroke", 0xFFFFFFFFu));
  DC_TRY(max_rate, lim.uint("max_strokes_per_second", 0xFFFFFFFFu));
  DC_TRY(max_open, lim.uint("max_open_strokes", 0xFFFFFFFFu));
  DC_TRY(min_r, lim.number("min_radius_m", 0.0, 1e12));
  DC_TRY(max_r, lim.number("max_radius_m", 0.0, 1e12));
  if (min_r > max_r) return out_of_range("field 'limits.min_radius_m' exceeds 'max_radius_m'");
  std::uint64_t receipts = 0;  // a server from before client ids remembers no strokes
  if (lim.has("stroke_receipts")) {
    DC_TRY(r, lim.uint("stroke_receipts", 0xFFFFFFFFu));
    receipts = r;
  }
  double max_extent = 0;  // absent: not stated
  if (lim.has("max_stroke_extent_m")) {
    DC_TRY(e, lim.number("max_stroke_extent_m", 0.0, 1e12));
    max_extent = e;
  }
  std::uint64_t max_cells = 0;
  if (lim.has("max_stroke_cells")) {
    DC_TRY(c, lim.uint("max_stroke_cells"));
    max_cells = c;
  }
  std::uint64_t undo_depth = 0, undo_bytes = 0;  // absent: a server without undo
  if (lim.has("undo_depth")) {
    DC_TRY(d, lim.uint("undo_depth", 0xFFFFFFFFu));
    undo_depth = d;
  }
  if (lim.has("undo_max_stroke_bytes")) {
    DC_TRY(b, lim.uint("undo_max_stroke_bytes"));
    undo_bytes = b;
  }
  m.role = role;
  m.canvas = std::move(canvas);
  m.geometry = {static_cast<std::uint32_t>(rpa), edge, static_cast<int>(depth)};
  m.block_cells = static_cast<std::uint32_t>(block_cells);
  m.texture_width = static_cast<std::uint32_t>(tw);
  m.epoch = epoch;
  m.pool_layout = {std::move(pl_id), static_cast<std::uint32_t>(pl_version)};
  m.limits = {max_frame,
              static_cast<std::uint32_t>(max_samples),
              static_cast<std::uint32_t>(max_rate),
              static_cast<std::uint32_t>(max_open),
              min_r,
              max_r,
              static_cast<std::uint32_t>(receipts),
              max_extent,
              max_cells,
              static_cast<std::uint32_t>(undo_depth),
              undo_bytes};
  return Message(std::move(m));
}

Result<Message> read_stroke(const Obj& o, const DecodeOptions& opt, MessageRef* about) {
  DC_TRY(h, read_handle(o, about));
  DC_TRY(brush_obj, o.object("brush"));
  DC_TRY(brush, read_brush(brush_obj));
  DC_TRY(samples, read_samples(o, false, opt));
  DC_TRY(stroke, ValidatedStroke::make(brush, std::move(samples)));
  return Message(DecodedStroke{h, std::move(stroke)});
}

Result<Message> read_stroke_begin(const Obj& o, const DecodeOptions& opt, MessageRef* about) {
  DC_TRY(h, read_handle(o, about));
  DC_TRY(brush_obj, o.object("brush"));
  DC_TRY(brush, read_brush(brush_obj));
  ValidatedSamples samples;
  if (o.has("samples")) {
    DC_TRY(read, read_samples(o, true, opt));
    samples = std::move(read);
  }
  return Message(DecodedStrokeBegin{h, brush, std::move(samples)});
}

Result<Message> read_stroke_samples(const Obj& o, const DecodeOptions& opt, MessageRef* about) {
  DC_TRY(h, read_handle(o, about));
  DC_TRY(samples, read_samples(o, false, opt));
  return Message(DecodedStrokeSamples{h, std::move(samples)});
}

Result<Message> read_pick_up(const Obj& o, const DecodeOptions& opt, MessageRef* about) {
  PickUp m;
  DC_TRY(id, read_handle(o, about, "request_id"));
  DC_TRY(pos, o.array("position"));
  if (pos->size() != 3) return malformed("field 'position' must hold 3 numbers");
  const double half = opt.bounds.edge_m * 0.5;
  for (std::size_t i = 0; i < 3; ++i) {
    DC_TRY(v, Obj::number_value((*pos)[i], "position[" + std::to_string(i) + "]", -half, half));
    m.position[i] = v;
  }
  m.request_id = id;
  return Message(m);
}

Result<Message> read_pick_up_reply(const Obj& o, MessageRef* about) {
  PickUpReply m;
  DC_TRY(id, read_handle(o, about, "request_id"));
  DC_TRY(colour, o.array("colour"));
  if (colour->size() != 3) return malformed("field 'colour' must hold 3 numbers");
  for (std::size_t i = 0; i < 3; ++i) {
    DC_TRY(v, Obj::number_value((*colour)[i], "colour[" + std::to_string(i) + "]", 0.0, 1.0));
    m.colour[i] = static_cast<float>(v);
  }
  DC_TRY(density, o.number("density", 0.0, 1.0));
  DC_TRY(depth, o.uint("depth", 24));
  m.request_id = id;
  m.density = static_cast<float>(density);
  m.depth = static_cast<int>(depth);
  return Message(m);
}

Result<Message> read_error(const Obj& o, MessageRef* about) {
  ErrorMessage m;
  DC_TRY(code_name, o.string("code", 64));
  auto code = parse_errc(code_name);
  if (!code) return out_of_range("field 'code': unknown error code '" + code_name + "'");
  DC_TRY(message, o.string("message", 4096));
  m.code = *code;
  m.message = std::move(message);
  if (o.has("in_reply_to")) {
    DC_TRY(r, o.string("in_reply_to", 64));
    m.in_reply_to = std::move(r);
  }
  if (o.has("handle")) {
    DC_TRY(h, read_handle(o, about));
    m.handle = h;
  }
  if (o.has("fatal")) {
    DC_TRY(f, o.boolean("fatal"));
    m.fatal = f;
  }
  return Message(std::move(m));
}

Result<Message> read_stats(const Obj& o) {
  Stats m;
  DC_TRY(epoch, o.uint("epoch"));
  DC_TRY(strokes, o.uint("strokes"));
  DC_TRY(live, o.uint("live_cells"));
  DC_TRY(clients, o.uint("clients"));
  DC_TRY(blocks, o.uint("blocks_sent"));
  DC_TRY(bytes, o.uint("bytes_sent"));
  DC_TRY(queue, o.uint("queue_blocks"));
  m = {epoch, strokes, live, clients, blocks, bytes, queue};
  return Message(m);
}

Result<Message> read_epoch_end(const Obj& o) {
  EpochEnd m;
  DC_TRY(epoch, o.uint("epoch"));
  DC_TRY(blocks, o.uint("blocks", 0xFFFFFFFFu));
  DC_TRY(caught_up, o.boolean("caught_up"));
  m = {epoch, static_cast<std::uint32_t>(blocks), caught_up};
  return Message(m);
}

// ---- presence ----

Result<std::array<double, 3>> read_point(const Obj& o, std::string_view key, double limit) {
  DC_TRY(arr, o.array(key));
  if (arr->size() != 3) return malformed("field '" + o.name(key) + "' must hold 3 numbers");
  std::array<double, 3> p{};
  for (std::size_t i = 0; i < 3; ++i) {
    DC_TRY(v, Obj::number_value((*arr)[i], o.name(key) + "[" + std::to_string(i) + "]", -limit,
                                limit));
    p[i] = v;
  }
  return p;
}

// The fields of a painter's presence (the same in both directions). Every field is required
// except `cursor`, which is read (and must be inside the canvas) only when `cursor_on_canvas`.
Result<Presence> read_presence_fields(const Obj& o, const DecodeOptions& opt) {
  Presence p;
  DC_TRY(on_canvas, o.boolean("cursor_on_canvas"));
  p.cursor_on_canvas = on_canvas;
  if (on_canvas) {
    DC_TRY(cursor, read_point(o, "cursor", opt.bounds.edge_m * 0.5));
    p.cursor = cursor;
  }
  DC_TRY(eye, read_point(o, "eye", kPresenceMaxMetres));
  DC_TRY(target, read_point(o, "target", kPresenceMaxMetres));
  if (eye == target) return out_of_range("field 'target' must differ from 'eye'");
  p.eye = eye;
  p.target = target;
  DC_TRY(vfov, o.number("vfov_deg", 0.0, 179.0));
  if (!(vfov > 0.0 && vfov < 179.0))
    return out_of_range("field 'vfov_deg' must be within (0, 179) degrees");
  p.vfov_deg = vfov;
  DC_TRY(colour, o.array("colour"));
  if (colour->size() != 4) return malformed("field 'colour' must hold 4 numbers");
  for (std::size_t c = 0; c < 4; ++c) {
    DC_TRY(v, Obj::number_value((*colour)[c], "colour[" + std::to_string(c) + "]", 0.0, 1.0));
    p.colour[c] = static_cast<float>(v);
  }
  DC_TRY(size, o.number("size_m", 0.0, kPresenceMaxMetres));
  p.size_m = size;
  DC_TRY(mode_name, o.string("mode", 32));
  auto mode = parse_brush_mode(mode_name);
  if (!mode) return out_of_range("field 'mode': " + mode.error().message);
  p.mode = *mode;
  DC_TRY(painting, o.boolean("painting"));
  p.painting = painting;
  return p;
}

Result<Message> read_presence(const Obj& o, const DecodeOptions& opt) {
  if (!o.has("artist")) {
    DC_TRY(p, read_presence_fields(o, opt));
    return Message(p);
  }
  PresenceUpdate m;
  DC_TRY(artist, o.uint("artist"));
  DC_TRY(name, o.string("name", 128));
  DC_TRY(gone, o.boolean("gone"));
  m.artist = artist;
  m.name = std::move(name);
  m.gone = gone;
  if (!gone) {
    DC_TRY(p, read_presence_fields(o, opt));
    m.presence = p;
  }
  return Message(std::move(m));
}

json presence_json(json j, const Presence& p) {
  j["cursor_on_canvas"] = p.cursor_on_canvas;
  if (p.cursor_on_canvas) j["cursor"] = {p.cursor[0], p.cursor[1], p.cursor[2]};
  j["eye"] = {p.eye[0], p.eye[1], p.eye[2]};
  j["target"] = {p.target[0], p.target[1], p.target[2]};
  j["vfov_deg"] = p.vfov_deg;
  j["colour"] = {p.colour[0], p.colour[1], p.colour[2], p.colour[3]};
  j["size_m"] = p.size_m;
  j["mode"] = brush_mode_name(p.mode);
  j["painting"] = p.painting;
  return j;
}

// Nesting depth outside strings, checked before parsing so that no parser state grows with
// hostile input.
bool nesting_within(std::string_view text, int max_depth) {
  int depth = 0;
  bool in_string = false;
  for (std::size_t i = 0; i < text.size(); ++i) {
    const char c = text[i];
    if (in_string) {
      if (c == '\\')
        ++i;
      else if (c == '"')
        in_string = false;
      continue;
    }
    if (c == '"')
      in_string = true;
    else if (c == '{' || c == '[') {
      if (++depth > max_depth) return false;
    } else if (c == '}' || c == ']') {
      --depth;
    }
  }
  return true;
}

struct Encoder {
  json operator()(const Hello& m) const {
    json j = {{"type", "hello"},           {"protocol_version", m.protocol_version},
              {"role", role_name(m.role)}, {"token", m.token},
              {"canvas", m.canvas},        {"client_name", m.client_name}};
    if (m.delta_frames) j["delta_frames"] = true;
    if (m.frame_bundles) j["frame_bundles"] = true;
    if (!m.block_frames) j["block_frames"] = false;
    if (!m.client_id.empty()) j["client_id"] = m.client_id;
    if (m.batch_interval_ms != 0) j["batch_interval_ms"] = m.batch_interval_ms;
    if (m.camera)
      j["camera"] = {{"eye", {m.camera->eye[0], m.camera->eye[1], m.camera->eye[2]}},
                     {"target", {m.camera->target[0], m.camera->target[1], m.camera->target[2]}}};
    return j;
  }
  json operator()(const Welcome& m) const {
    return {{"type", "welcome"},
            {"protocol_version", m.protocol_version},
            {"role", role_name(m.role)},
            {"canvas", m.canvas},
            {"geometry",
             {{"roots_per_axis", m.geometry.roots_per_axis},
              {"edge_m", m.geometry.edge_m},
              {"max_depth", m.geometry.max_depth}}},
            {"block_cells", m.block_cells},
            {"texture_width", m.texture_width},
            {"epoch", m.epoch},
            {"pool_layout", {{"id", m.pool_layout.id}, {"version", m.pool_layout.version}}},
            {"limits",
             {{"max_frame_bytes", m.limits.max_frame_bytes},
              {"max_samples_per_stroke", m.limits.max_samples_per_stroke},
              {"max_strokes_per_second", m.limits.max_strokes_per_second},
              {"max_open_strokes", m.limits.max_open_strokes},
              {"min_radius_m", m.limits.min_radius_m},
              {"max_radius_m", m.limits.max_radius_m},
              {"stroke_receipts", m.limits.stroke_receipts},
              {"max_stroke_extent_m", m.limits.max_stroke_extent_m},
              {"max_stroke_cells", m.limits.max_stroke_cells},
              {"undo_depth", m.limits.undo_depth},
              {"undo_max_stroke_bytes", m.limits.undo_max_stroke_bytes}}}};
  }
  json operator()(const StrokeMessage& m) const {
    return {{"type", "stroke"},
            {"handle", m.handle},
            {"brush", brush_json(m.stroke.brush)},
            {"samples", samples_json(m.stroke.samples)}};
  }
  json operator()(const StrokeBegin& m) const {
    json j = {{"type", "stroke_begin"}, {"handle", m.handle}, {"brush", brush_json(m.brush)}};
    if (!m.samples.empty()) j["samples"] = samples_json(m.samples);
    return j;
  }
  json operator()(const StrokeSamples& m) const {
    return {{"type", "stroke_samples"}, {"handle", m.handle}, {"samples", samples_json(m.samples)}};
  }
  json operator()(const DecodedStroke& m) const {
    return {{"type", "stroke"},
            {"handle", m.handle},
            {"brush", brush_json(m.stroke.brush().get())},
            {"samples", samples_json(m.stroke.samples().span())}};
  }
  json operator()(const DecodedStrokeBegin& m) const {
    json j = {{"type", "stroke_begin"}, {"handle", m.handle}, {"brush", brush_json(m.brush.get())}};
    if (!m.samples.empty()) j["samples"] = samples_json(m.samples.span());
    return j;
  }
  json operator()(const DecodedStrokeSamples& m) const {
    return {{"type", "stroke_samples"},
            {"handle", m.handle},
            {"samples", samples_json(m.samples.span())}};
  }
  json operator()(const StrokeEnd& m) const {
    return {{"type", "stroke_end"}, {"handle", m.handle}};
  }
  json operator()(const Ack& m) const {
    return {{"type", "ack"}, {"handle", m.handle}, {"stroke_id", m.stroke_id}, {"epoch", m.epoch}};
  }
  json operator()(const PickUp& m) const {
    return {{"type", "pick_up"},
            {"request_id", m.request_id},
            {"position", {m.position[0], m.position[1], m.position[2]}}};
  }
  json operator()(const PickUpReply& m) const {
    return {{"type", "pick_up_reply"},
            {"request_id", m.request_id},
            {"colour", {m.colour[0], m.colour[1], m.colour[2]}},
            {"density", m.density},
            {"depth", m.depth}};
  }
  json operator()(const Undo& m) const { return {{"type", "undo"}, {"request_id", m.request_id}}; }
  json operator()(const Redo& m) const { return {{"type", "redo"}, {"request_id", m.request_id}}; }
  json operator()(const UndoReply& m) const {
    return {{"type", "undo_reply"},
            {"request_id", m.request_id},
            {"stroke_id", m.stroke_id},
            {"epoch", m.epoch},
            {"redo", m.redo}};
  }
  json operator()(const Import& m) const { return detail::import_json(m); }
  json operator()(const ImportReply& m) const { return detail::import_reply_json(m); }
  json operator()(const ExportRequest& m) const { return detail::export_json(m); }
  json operator()(const ExportReply& m) const { return detail::export_reply_json(m); }
  json operator()(const PlaybackStep& m) const { return detail::playback_step_json(m); }
  json operator()(const PlaybackPosition& m) const { return detail::playback_position_json(m); }
  json operator()(const ErrorMessage& m) const {
    json j = {{"type", "error"}, {"code", errc_name(m.code)}, {"message", m.message}};
    if (!m.in_reply_to.empty()) j["in_reply_to"] = m.in_reply_to;
    if (m.handle) j["handle"] = *m.handle;
    if (m.fatal) j["fatal"] = true;
    return j;
  }
  json operator()(const StatsRequest&) const { return {{"type", "stats_request"}}; }
  json operator()(const Stats& m) const {
    return {{"type", "stats"},
            {"epoch", m.epoch},
            {"strokes", m.strokes},
            {"live_cells", m.live_cells},
            {"clients", m.clients},
            {"blocks_sent", m.blocks_sent},
            {"bytes_sent", m.bytes_sent},
            {"queue_blocks", m.queue_blocks}};
  }
  json operator()(const Presence& m) const { return presence_json({{"type", "presence"}}, m); }
  json operator()(const PresenceUpdate& m) const {
    json j = {{"type", "presence"}, {"artist", m.artist}, {"name", m.name}, {"gone", m.gone}};
    return m.gone ? j : presence_json(std::move(j), m.presence);
  }
  json operator()(const EpochEnd& m) const {
    return {{"type", "epoch_end"},
            {"epoch", m.epoch},
            {"blocks", m.blocks},
            {"caught_up", m.caught_up}};
  }
};

}  // namespace

std::string_view role_name(Role role) noexcept {
  switch (role) {
    case Role::painter:
      return "painter";
    case Role::viewer:
      return "viewer";
  }
  return "unknown";
}

Result<Role> parse_role(std::string_view name) {
  if (name == "painter") return Role::painter;
  if (name == "viewer") return Role::viewer;
  return make_error(Errc::invalid_argument,
                    "unknown role '" + std::string(name) + "' (painter or viewer)");
}

bool is_valid_canvas_name(std::string_view name) noexcept {
  if (name.empty() || name.size() > 64) return false;
  for (char c : name) {
    const bool ok = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') ||
                    c == '.' || c == '_' || c == '-';
    if (!ok) return false;
  }
  return true;
}

bool is_valid_token(std::string_view token) noexcept {
  if (token.empty() || token.size() > 256) return false;
  for (char c : token)
    if (c < 0x21 || c > 0x7E) return false;
  return true;
}

bool is_valid_client_id(std::string_view id) noexcept {
  if (id.empty() || id.size() > 64) return false;
  for (char c : id) {
    const bool ok = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') ||
                    c == '_' || c == '-';
    if (!ok) return false;
  }
  return true;
}

Result<Errc> parse_errc(std::string_view name) {
  for (Errc e : kAllErrc)
    if (errc_name(e) == name) return e;
  return make_error(Errc::not_found, "unknown error code '" + std::string(name) + "'");
}

std::string_view message_type(const Message& message) noexcept {
  constexpr std::string_view kNames[] = {
      "hello",     "welcome", "stroke",        "stroke_begin",  "stroke_samples", "stroke_end",
      "ack",       "pick_up", "pick_up_reply", "error",         "stats_request",  "stats",
      "epoch_end", "presence", "presence",     "stroke",        "stroke_begin",   "stroke_samples",
      "undo",      "redo",     "undo_reply",    "import",        "import_reply",  "export",
      "export_reply", "playback_step", "playback_position"};
  static_assert(std::size(kNames) == std::variant_size_v<Message>);
  return kNames[message.index()];
}

std::string encode_message(const Message& message) {
  return std::visit(Encoder{}, message).dump(-1, ' ', false, json::error_handler_t::replace);
}

Result<Message> decode_message(std::string_view text, const DecodeOptions& opt, MessageRef* about) {
  if (about) *about = {};
  if (text.size() > opt.max_bytes)
    return make_error(Errc::limit_exceeded, "message of " + std::to_string(text.size()) +
                                                " bytes exceeds the limit of " +
                                                std::to_string(opt.max_bytes));
  if (!nesting_within(text, opt.max_nesting))
    return make_error(Errc::limit_exceeded,
                      "message nests deeper than " + std::to_string(opt.max_nesting));
  const json j = json::parse(text, nullptr, /*allow_exceptions=*/false);
  if (j.is_discarded()) return malformed("message is not valid JSON (UTF-8)");
  if (!j.is_object()) return malformed("message must be a JSON object");
  const Obj o(j, "");
  DC_TRY(type, o.string("type", 64));
  if (about) about->type = type;
  if (type == "hello") return read_hello(o);
  if (type == "welcome") return read_welcome(o);
  if (type == "stroke") return read_stroke(o, opt, about);
  if (type == "stroke_begin") return read_stroke_begin(o, opt, about);
  if (type == "stroke_samples") return read_stroke_samples(o, opt, about);
  if (type == "stroke_end") {
    DC_TRY(h, read_handle(o, about));
    return Message(StrokeEnd{h});
  }
  if (type == "ack") {
    DC_TRY(h, read_handle(o, about));
    DC_TRY(id, o.uint("stroke_id"));
    DC_TRY(epoch, o.uint("epoch"));
    return Message(Ack{h, id, epoch});
  }
  if (type == "pick_up") return read_pick_up(o, opt, about);
  if (type == "pick_up_reply") return read_pick_up_reply(o, about);
  if (type == "error") return read_error(o, about);
  if (type == "stats_request") return Message(StatsRequest{});
  if (type == "stats") return read_stats(o);
  if (type == "epoch_end") return read_epoch_end(o);
  if (type == "presence") return read_presence(o, opt);
  if (type == "undo" || type == "redo") {
    DC_TRY(id, read_handle(o, about, "request_id"));
    return type == "undo" ? Message(Undo{id}) : Message(Redo{id});
  }
  if (type == "undo_reply") {
    DC_TRY(id, read_handle(o, about, "request_id"));
    DC_TRY(stroke, o.uint("stroke_id"));
    DC_TRY(epoch, o.uint("epoch"));
    DC_TRY(redo, o.boolean("redo"));
    return Message(UndoReply{id, stroke, epoch, redo});
  }
  if (type == "import") return detail::read_import(o, opt, about);
  if (type == "import_reply") return detail::read_import_reply(o, about);
  if (type == "export") return detail::read_export(o, opt, about);
  if (type == "export_reply") return detail::read_export_reply(o, opt, about);
  if (type == "playback_step") return detail::read_playback_step(o, about);
  if (type == "playback_position") return detail::read_playback_position(o, opt, about);
  if (about) about->type.clear();  // do not echo arbitrary client text as a type
  return malformed("unknown message type '" + type.substr(0, 64) + "'");
}

ErrorMessage to_error_message(const Error& error, const MessageRef& about, bool fatal) {
  ErrorMessage m;
  m.code = error.code;
  m.message = error.message;
  m.in_reply_to = about.type;
  m.handle = about.handle;
  m.fatal = fatal;
  return m;
}

}  // namespace deepcanvas::protocol
