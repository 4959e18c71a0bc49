// The history playback messages (PROTOCOL.md 3.13): playback_step and playback_position.
#include "json_fields.hpp"

namespace deepcanvas::protocol::detail {

namespace {
constexpr double kMaxStepSeconds = 1e9;  // about 31 years of painting time
}  // namespace

json playback_step_json(const PlaybackStep& m) {
  return {{"type", "playback_step"},
          {"request_id", m.request_id},
          {"strokes", m.strokes},
          {"seconds", m.seconds}};
}

json playback_position_json(const PlaybackPosition& m) {
  json j = {{"type", "playback_position"},
            {"request_id", m.request_id},
            {"epoch", m.epoch},
            {"events", m.events},
            {"events_total", m.events_total},
            {"strokes", m.strokes},
            {"strokes_total", m.strokes_total},
            {"painting_seconds", m.painting_seconds},
            {"painting_seconds_total", m.painting_seconds_total},
            {"timed", m.timed}};
  if (m.bounds) j["bounds"] = *m.bounds;
  return j;
}

Result<Message> read_playback_step(const Obj& o, MessageRef* about) {
  PlaybackStep m;
  DC_TRY(id, o.uint("request_id"));
  m.request_id = id;
  if (about) about->handle = id;
  DC_TRY(strokes, o.uint("strokes"));
  m.strokes = strokes;
  DC_TRY(seconds, o.number("seconds", 0, kMaxStepSeconds));
  m.seconds = seconds;
  if (m.strokes != 0 && m.seconds != 0)
    return out_of_range("a playback step is 'strokes' or 'seconds', not both");
  return Message(m);
}

Result<Message> read_playback_position(const Obj& o, const DecodeOptions& opt, MessageRef* about) {
  PlaybackPosition m;
  DC_TRY(id, o.uint("request_id"));
  m.request_id = id;
  if (about) about->handle = id;
  DC_TRY(epoch, o.uint("epoch"));
  m.epoch = epoch;
  DC_TRY(events, o.uint("events"));
  DC_TRY(events_total, o.uint("events_total"));
  DC_TRY(strokes, o.uint("strokes"));
  DC_TRY(strokes_total, o.uint("strokes_total"));
  if (events > events_total || strokes > strokes_total)
    return out_of_range("a playback position past the end of its history");
  m.events = events;
  m.events_total = events_total;
  m.strokes = strokes;
  m.strokes_total = strokes_total;
  DC_TRY(t, o.number("painting_seconds", 0, 1e12));
  DC_TRY(t_total, o.number("painting_seconds_total", 0, 1e12));
  m.painting_seconds = t;
  m.painting_seconds_total = t_total;
  DC_TRY(timed, o.boolean("timed"));
  m.timed = timed;
  if (o.has("bounds")) {
    DC_TRY(box, read_box(o, "bounds", opt.bounds.edge_m));
    m.bounds = box;
  }
  return Message(m);
}

}  // namespace deepcanvas::protocol::detail
