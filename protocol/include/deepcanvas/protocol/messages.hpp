// Control messages: JSON text frames, one message per WebSocket text frame, each an object with
// a "type". PROTOCOL.md describes every message field by field; this header is its C++ face.
//
// Untrusted input: decode_message() accepts any bytes. It never throws, bounds the text size and
// the nesting depth before parsing, checks every field's JSON type and range, rejects unknown
// message types and missing fields (naming the field), and is the boundary where bytes become a
// stroke: it makes the stroke payloads ValidatedStroke / ValidatedBrush / ValidatedSamples
// (stroke.hpp) with the canvas bounds and limits given, so the decoded stroke messages
// (DecodedStroke, DecodedStrokeBegin, DecodedStrokeSamples) go to a canvas without another check.
// Unknown extra fields are ignored (so a later minor revision may add optional fields).
//
// Integers (handles, ids, epochs, counters) are limited to kMaxJsonInteger (2^53 - 1) so that
// every JSON implementation reads them exactly.
//
// Threading: all functions are pure; encode/decode may run concurrently on different data.
#pragma once

#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <variant>
#include <vector>

#include "deepcanvas/base/result.hpp"
#include "deepcanvas/protocol/stroke.hpp"
#include "deepcanvas/protocol/version.hpp"

namespace deepcanvas::protocol {

enum class Role : std::uint8_t { painter = 0, viewer = 1 };
std::string_view role_name(Role role) noexcept;
Result<Role> parse_role(std::string_view name);

// Canvas names: 1 to 64 characters from [A-Za-z0-9._-].
bool is_valid_canvas_name(std::string_view name) noexcept;
// Tokens: 1 to 256 printable ASCII characters, no spaces (0x21..0x7E).
bool is_valid_token(std::string_view token) noexcept;
// Client ids (Hello::client_id): 1 to 64 characters from [A-Za-z0-9_-].
bool is_valid_client_id(std::string_view id) noexcept;
// The inverse of errc_name(); not_found for a name no Errc has.
Result<Errc> parse_errc(std::string_view name);

// ---- handshake ----

// Where a joining client's camera is (Hello::camera): the eye and the point it looks at, metres,
// finite, |v| <= 1e12 each, eye != target (as in Presence).
struct JoinCamera {
  std::array<double, 3> eye{}, target{};
  friend bool operator==(const JoinCamera&, const JoinCamera&) = default;
};

// client -> server, the first message of every connection.
struct Hello {
  std::uint32_t protocol_version = kProtocolVersion;
  Role role = Role::viewer;
  std::string token;
  std::string canvas;
  std::string client_name;  // free text for logs, at most 128 bytes
  // Optional (absent = false): the client can apply temporal delta block frames (PROTOCOL.md
  // 4.7), so the server may send a block as a delta against the version this client holds.
  bool delta_frames = false;
  // Optional (absent = false): the client decodes frame bundles (PROTOCOL.md 4.12), so the server
  // may send the block frames of a live batch as one compressed message.
  bool frame_bundles = false;
  // Optional (absent = true): false asks for no canvas stream at all (no snapshot, no block
  // frames, no epoch_end), for clients that only paint, pick or ask for stats: acks, errors,
  // pick-up replies and stats still come.
  bool block_frames = true;
  // Optional (absent = empty = none): names this painter across reconnects, 1..64 characters of
  // [A-Za-z0-9_-], chosen at random by the client once per run. With it a stroke is named by
  // (canvas, client_id, handle): the server paints a resent stroke once and answers the resend
  // with the first one's ack (PROTOCOL.md 3.3.1), so a client may resend what was not acked
  // after a reconnect.
  std::string client_id;
  // Optional (absent = 0): the least time, in milliseconds (0..kMaxBatchIntervalMs), between the
  // starts of two epoch batches to this client. Versions published meanwhile coalesce into the
  // next batch (a block painted three times goes once), so a client on a thin link, or one that
  // shows the canvas less often than epochs come, gets fewer bytes for the same canvas.
  std::uint32_t batch_interval_ms = 0;
  // Optional (absent = none): the client's camera. A snapshot sends the blocks of one depth
  // nearest this camera first (PROTOCOL.md 4.4), so a progressive join refines what the client
  // looks at before what lies far away or behind it.
  std::optional<JoinCamera> camera;
};
inline constexpr std::uint32_t kMaxBatchIntervalMs = 1000;

struct CanvasGeometry {
  std::uint32_t roots_per_axis = 4;  // even, 2..64
  double edge_m = 20000.0;           // > 0, finite
  int max_depth = 24;                // 1..24
};

struct PoolLayout {
  std::string id{kPoolLayoutId};
  std::uint32_t version = kPoolLayoutVersion;
};

// What the server enforces on this session (so a client can stay within it).
struct SessionLimits {
  std::uint64_t max_frame_bytes = 16u << 20;  // largest text frame the server reads
  std::uint32_t max_samples_per_stroke = 100000;
  std::uint32_t max_strokes_per_second = 100;
  std::uint32_t max_open_strokes = 16;  // streamed strokes begun and not yet ended
  double min_radius_m = 1e-5;
  double max_radius_m = 1000.0;
  // Strokes the server remembers per client id (Hello::client_id) to answer resends: the
  // `stroke_receipts` highest handles it accepted. A client keeps the strokes it sent after its
  // oldest unacknowledged one below this, so a resend after a reconnect is always recognised.
  // 0: the server remembers no strokes (a resend is painted again). Optional in a welcome
  // (absent: 0, a server from before client ids).
  std::uint32_t stroke_receipts = 256;
  // The canvas's StrokeLimits (stroke.hpp) that bound one stroke's work: the largest edge of a
  // stroke's box (sample positions inflated by radius; past it: refused up front), and the cells
  // one stroke may create (past it: stopped with limit_exceeded, its paint kept). The welcome
  // states the joined canvas's. Optional in a welcome (absent: 0, not stated).
  double max_stroke_extent_m = StrokeLimits{}.max_extent_m;
  std::uint64_t max_stroke_cells = StrokeLimits{}.max_stroke_cells;
  // Undo (PROTOCOL.md 3.10): how many of a painter's latest strokes it may undo, and the largest
  // encoded change of one stroke the history keeps (a stroke past it cannot be undone; its undo
  // is refused with limit_exceeded). Optional in a welcome (absent: 0, no undo).
  std::uint32_t undo_depth = 100;
  std::uint64_t undo_max_stroke_bytes = 4u << 20;
};

// server -> client, the answer to an accepted hello.
struct Welcome {
  std::uint32_t protocol_version = kProtocolVersion;
  Role role = Role::viewer;  // the role granted
  std::string canvas;
  CanvasGeometry geometry;
  std::uint32_t block_cells = 4096;     // cells per block, a power of two, 64..2^20
  std::uint32_t texture_width = 16384;  // GPU texture width the pools map to, power of two
  std::uint64_t epoch = 0;              // the server's current epoch at join
  PoolLayout pool_layout;
  SessionLimits limits;
};

// ---- strokes (client -> server; painters only) ----
// A sender fills StrokeMessage / StrokeBegin / StrokeSamples with plain values (encoding does not
// validate, so a test can send a bad stroke); decode_message returns the Decoded* forms below,
// which carry the same fields validated. Both forms encode to the same JSON.

// A whole stroke. `handle` is chosen by the client and echoed in the ack (and in errors about
// this stroke). stroke.id is not sent; decode leaves it 0.
struct StrokeMessage {
  std::uint64_t handle = 0;
  Stroke stroke;
};

// A stroke streamed while it is drawn: begin (brush, maybe first samples), samples..., end.
struct StrokeBegin {
  std::uint64_t handle = 0;
  Brush brush;
  std::vector<StrokeSample> samples;  // may be empty
};
struct StrokeSamples {
  std::uint64_t handle = 0;
  std::vector<StrokeSample> samples;  // at least one
};
struct StrokeEnd {
  std::uint64_t handle = 0;
};

// What decode_message makes of "stroke", "stroke_begin" and "stroke_samples".
struct DecodedStroke {
  std::uint64_t handle = 0;
  ValidatedStroke stroke;  // id 0
};
struct DecodedStrokeBegin {
  std::uint64_t handle = 0;
  ValidatedBrush brush;
  ValidatedSamples samples;  // may be empty
};
struct DecodedStrokeSamples {
  std::uint64_t handle = 0;
  ValidatedSamples samples;  // at least one
};

// server -> client: the stroke `handle` was ordered as `stroke_id` and its effect is complete in
// epoch `epoch` (visible once that epoch's epoch_end has been applied).
struct Ack {
  std::uint64_t handle = 0;
  std::uint64_t stroke_id = 0;
  std::uint64_t epoch = 0;
};

// ---- pick-up (colour picker) ----
struct PickUp {  // client -> server
  std::uint64_t request_id = 0;
  double position[3] = {0, 0, 0};  // metres, inside the canvas
};
struct PickUpReply {  // server -> the asking client only
  std::uint64_t request_id = 0;
  float colour[3] = {0, 0, 0};  // the leaf's RGB, 0..1 (byte / 255)
  float density = 0;            // the leaf's alpha, 0..1 (byte / 255)
  int depth = 0;                // the leaf's depth, 0..24
};

// ---- undo and redo (PROTOCOL.md 3.10; painters only) ----
// client -> server: take back this painter's latest stroke not yet undone (its own strokes only,
// whoever painted since), or restore the latest one it undid. Ordered like a stroke: after the
// strokes this painter sent before it. Counted against max_strokes_per_second.
struct Undo {
  std::uint64_t request_id = 0;
};
struct Redo {
  std::uint64_t request_id = 0;
};
// server -> the asking client: stroke `stroke_id` was taken back (redo false) or restored (redo
// true); the change is complete in epoch `epoch`, and durable like a stroke's ack.
struct UndoReply {
  std::uint64_t request_id = 0;
  std::uint64_t stroke_id = 0;
  std::uint64_t epoch = 0;
  bool redo = false;
};

// ---- import (PROTOCOL.md 3.11; painters only) ----
// client -> server: paste a volume or a mesh file into the canvas as one operation, ordered like
// a stroke of this painter and undoable like one. The file travels in the message (base64 in
// "data"), so it must fit one message (welcome.limits.max_frame_bytes, about 3/4 of it as file
// bytes). The server converts it into cells (OpenVDB's readers; meshes through OpenVDB's
// mesh-to-volume) and answers with ImportReply or an error; a file that does not convert changes
// nothing.
struct Import {
  std::uint64_t request_id = 0;
  std::string format;                 // "vdb", "gltf", "glb" or "ply"
  std::array<double, 3> at{};         // canvas metres: where the file's origin goes (in the canvas)
  double scale = 1;                   // metres per file unit, (0, 1e9]
  double voxel_size_m = 0;            // cell edge to import at (nearest level); 0: the file's own
                                      // voxel size (vdb), or 1/128 of the mesh's size
  std::array<float, 3> colour{1, 1, 1};  // where the file has no colour, each 0..1
  double density_scale = 1;           // fog volumes: extinction per metre = value x this, (0, 1e9]
  std::vector<std::uint8_t> data;     // the file (at least 1 byte)
};
// server -> the asking client: the import is operation `stroke_id` (undo takes it back), complete
// in epoch `epoch` and durable like a stroke's ack; `cells` cells were pasted.
struct ImportReply {
  std::uint64_t request_id = 0;
  std::uint64_t stroke_id = 0;
  std::uint64_t epoch = 0;
  std::uint64_t cells = 0;
};

// ---- export through a running server (PROTOCOL.md 3.12; painters and viewers) ----
// client -> server: the canvas as a file, made by the server from the canvas as it stands once
// the strokes ordered before the request are painted. The file comes back in one message, so
// it must fit max_frame_bytes (about 3/4 of it as file bytes), and max_bytes if smaller.
struct ExportRequest {
  std::uint64_t request_id = 0;
  std::string format;          // "vdb", "gltf", "glb" or "ply"
  double voxel_size_m = 0;     // the voxel level (nearest octree level); 0: the format's default
  std::optional<std::array<double, 6>> box;  // x0 y0 z0 x1 y1 z1, canvas metres; none: all
  std::uint64_t max_bytes = 0;               // 0: as large as one message allows
};
// server -> the asking client: the file.
struct ExportReply {
  std::uint64_t request_id = 0;
  std::string format;
  std::vector<std::uint8_t> data;  // base64 on the wire
};

// ---- history playback (PROTOCOL.md 3.13; painters and viewers of a playback canvas) ----
// A playback canvas (deepcanvas-server playback) starts empty and paints a recorded history
// forward only when a client asks: a time-lapse renders it step by step.
// client -> server: paint the next `strokes` operations (a stroke's end, an undo, a redo or an
// import each count one), or up to the end of the next `seconds` mark of painting time. Both 0:
// nothing is painted; the answer says where the playback stands. Not both non-zero.
struct PlaybackStep {
  std::uint64_t request_id = 0;
  std::uint64_t strokes = 0;
  double seconds = 0;  // [0, 1e9]
};
// server -> the asking client, once `epoch` (holding everything painted so far) is published.
struct PlaybackPosition {
  std::uint64_t request_id = 0;
  std::uint64_t epoch = 0;
  std::uint64_t events = 0, events_total = 0;          // history events painted / in all
  std::uint64_t strokes = 0, strokes_total = 0;        // operations painted / in all
  double painting_seconds = 0;                         // painting time of the last event painted
  double painting_seconds_total = 0;                   // of the whole history
  bool timed = false;  // the history has painting times (`seconds` steps are possible)
  // Where the history paints (every sample's sphere and every import's cells), canvas metres
  // x0 y0 z0 x1 y1 z1; none for a history that paints nothing.
  std::optional<std::array<double, 6>> bounds;
};

// ---- errors, stats, epochs ----
struct ErrorMessage {  // server -> client
  Errc code = Errc::internal;
  std::string message;
  std::string in_reply_to;              // "type" of the message it answers; empty if none
  std::optional<std::uint64_t> handle;  // the stroke handle or pick-up request id, if known
  bool fatal = false;                   // the server closes the connection after sending it
};

struct StatsRequest {};  // client -> server

struct Stats {  // server -> client
  std::uint64_t epoch = 0;
  std::uint64_t strokes = 0;       // strokes applied on this canvas
  std::uint64_t live_cells = 0;    // cells in the canvas's tree
  std::uint64_t clients = 0;       // sessions receiving this canvas's stream (block_frames)
  std::uint64_t blocks_sent = 0;   // block frames sent to this session
  std::uint64_t bytes_sent = 0;    // block frame bytes sent to this session
  std::uint64_t queue_blocks = 0;  // blocks waiting in this session's send queue
};

// server -> client, after the block frames of `epoch`: the client applies the buffered blocks of
// that epoch together now. `blocks` counts this session's block frames in the epoch;
// `caught_up` is true when `epoch` is the canvas's newest epoch at the time of sending.
struct EpochEnd {
  std::uint64_t epoch = 0;
  std::uint32_t blocks = 0;
  bool caught_up = false;
};

// ---- presence (PROTOCOL.md 3.9): where the other artists' brushes and cameras are ----
// Wire type "presence" in both directions: a painter's own (client -> server, no "artist"), and
// the server's relay of another artist's (server -> client, with "artist", "name", "gone"). The
// decoder tells them apart by the "artist" field.

// client -> server (painters only): where this painter's brush and camera are. The server relays
// at most one per painter per 50 ms to the canvas's other clients (a newer one replaces one held
// back), so a client may send one per input event.
struct Presence {
  std::array<double, 3> cursor{};  // metres, the brush's 3D point; finite, inside the canvas
  bool cursor_on_canvas = false;   // false: the pointer is off the canvas (cursor not sent, 0)
  std::array<double, 3> eye{}, target{};  // the camera, metres, |v| <= 1e12 each, eye != target
  double vfov_deg = 45;                   // vertical field of view, (0, 179)
  std::array<float, 4> colour{};          // the brush colour rgb + density, each in [0, 1]
  double size_m = 0;                      // brush radius in metres, 0 .. 1e12
  BrushMode mode = BrushMode::paint;
  bool painting = false;  // a stroke is in progress
};

// server -> client: another artist's presence, or that it left.
struct PresenceUpdate {
  std::uint64_t artist = 0;  // the server's id for that connection, stable while it is connected
  std::string name;          // that artist's hello client_name (may be empty), at most 128 bytes
  bool gone = false;         // the artist left: drop it (presence fields then unspecified, 0)
  Presence presence;
};

using Message = std::variant<Hello, Welcome, StrokeMessage, StrokeBegin, StrokeSamples, StrokeEnd,
                             Ack, PickUp, PickUpReply, ErrorMessage, StatsRequest, Stats, EpochEnd,
                             Presence, PresenceUpdate, DecodedStroke, DecodedStrokeBegin,
                             DecodedStrokeSamples, Undo, Redo, UndoReply, Import, ImportReply,
                             ExportRequest, ExportReply, PlaybackStep, PlaybackPosition>;

// The wire "type" of a message: "hello", "welcome", "stroke", "stroke_begin", "stroke_samples",
// "stroke_end", "ack", "pick_up", "pick_up_reply", "error", "stats_request", "stats", "epoch_end",
// "presence" (both Presence and PresenceUpdate), "undo", "redo", "undo_reply", "import",
// "import_reply", "export", "export_reply", "playback_step", "playback_position"; a Decoded* message
// has the type of its plain form.
std::string_view message_type(const Message& message) noexcept;

struct DecodeOptions {
  CanvasBounds bounds;         // for stroke, pick-up and presence cursor positions
  StrokeLimits stroke_limits;  // for stroke samples (with `bounds`: the StrokeRules)
  std::size_t max_bytes = 16u << 20;
  int max_nesting = 8;  // objects/arrays inside each other; real messages need 4
};

// What decode_message could read about a message it rejected (for the error's in_reply_to).
struct MessageRef {
  std::string type;
  std::optional<std::uint64_t> handle;
};

// Encodes one message as compact JSON (UTF-8). Invalid UTF-8 in strings is replaced (U+FFFD).
// Encoding does not validate: encode what decode would accept.
std::string encode_message(const Message& message);

// Decodes one text frame. Errors: malformed (not JSON, not an object, wrong JSON type, unknown
// type, missing field), invalid_argument (a value out of range, a bad stroke), limit_exceeded
// (too big, too deep, too many samples), unsupported (hello/welcome of another protocol version).
// Stroke messages come back as DecodedStroke / DecodedStrokeBegin / DecodedStrokeSamples; a
// "presence" with an "artist" field as PresenceUpdate, without one as Presence.
// `about`, if given, receives the type and handle whenever they could be read.
Result<Message> decode_message(std::string_view text, const DecodeOptions& options = {},
                               MessageRef* about = nullptr);

// The error frame a server sends for a failed Result (e.g. from decode_message).
ErrorMessage to_error_message(const Error& error, const MessageRef& about = {}, bool fatal = false);

}  // namespace deepcanvas::protocol
