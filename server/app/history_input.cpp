// Reading a canvas's history for the offline commands and playback (history_input.hpp).
#include "history_input.hpp"

#include <algorithm>
#include <cstdio>
#include <cstring>

#include "deepcanvas/storage/canvas_store.hpp"

namespace deepcanvas::server_app {

void transform_samples(std::vector<protocol::StrokeSample>& samples, const paintings::ApaTransform& tf) {
  for (auto& p : samples) {
    p.x = p.x * tf.scale + tf.offset[0];
    p.y = p.y * tf.scale + tf.offset[1];
    p.z = p.z * tf.scale + tf.offset[2];
    p.radius = static_cast<float>(p.radius * tf.scale);
  }
}

std::optional<std::string> canvas_database(const std::string& path) {
  static constexpr char kMagic[] = "SQLite format 3";  // the first 16 bytes, NUL included
  for (const std::string& p : {path, path + storage::kCanvasFileSuffix}) {
    std::FILE* f = std::fopen(p.c_str(), "rb");
    if (!f) continue;
    char head[16] = {};
    const bool is_db = std::fread(head, 1, sizeof head, f) == sizeof head &&
                       std::memcmp(head, kMagic, sizeof head) == 0;
    std::fclose(f);
    if (is_db) return p;
  }
  return std::nullopt;
}

Result<std::vector<server_core::StrokeEvent>> load_history(const std::string& db,
                                                           std::uint64_t until,
                                                           server_core::OctreeConfig& shape) {
  auto history = storage::read_history(db);
  if (!history) return std::move(history).error();
  shape = history->config;
  auto& events = history->events;
  if (until != 0) {
    const auto end = std::find_if(events.begin(), events.end(), [&](const auto& e) {
      return e.kind == server_core::StrokeEvent::Kind::end && e.stroke_id == until;
    });
    if (end == events.end())
      return make_error(Errc::not_found,
                        db + ": stroke " + std::to_string(until) + " never ended in the history");
    events.erase(end + 1, events.end());
  }
  return std::move(events);
}

Result<std::vector<server_core::StrokeEvent>> load_input(const Input& in, const std::string& command) {
  auto bytes = paintings::read_file_bytes(in.path);
  if (!bytes) return std::move(bytes).error();
  std::vector<server_core::StrokeEvent> events;
  if (!server_core::looks_like_stroke_log(*bytes)) {
    // read_apa_file reads the file again so that its messages (not a painting, where it is
    // malformed) name the file the one way every command prints them.
    auto apa = paintings::read_apa_file(in.path, in.tf);
    if (!apa) return std::move(apa).error();
    std::uint64_t id = 0;
    for (auto& s : apa->strokes) {
      s.id = ++id;
      for (auto& e : server_core::stroke_events(s)) events.push_back(std::move(e));
    }
    return events;
  }
  auto log = server_core::read_stroke_log(*bytes);
  if (!log) return Error{log.error().code, in.path + ": " + log.error().message};
  if (log->tail)
    std::fprintf(stderr,
                 "%s: %s: stopped at offset %llu: %s (%zu events before it kept)\n",
                 command.c_str(), in.path.c_str(), static_cast<unsigned long long>(log->tail->offset),
                 log->tail->reason.c_str(), log->events.size());
  for (auto& e : log->events) transform_samples(e.samples, in.tf);
  return std::move(log->events);
}

}  // namespace deepcanvas::server_app
