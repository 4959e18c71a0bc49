// Reading a canvas's history: the event records, decoded and checked (load, tools).
#include <algorithm>
#include <filesystem>

#include "deepcanvas/storage/canvas_store.hpp"
#include "sqlite_util.hpp"
#include "store_impl.hpp"

namespace deepcanvas::storage {

Result<detail::EventScan> detail::scan_events(sqlite3* db, const std::string& where,
                                              std::uint64_t after, std::uint64_t until) {
  EventScan out;
  std::vector<std::uint8_t> buf = server_core::stroke_log_header();
  const std::size_t header = buf.size();
  std::uint64_t expect = after + 1;
  auto st = Stmt::prepare(
      db, "SELECT seq, stroke, kind, record, artist, time_ms FROM events WHERE seq > ? ORDER BY seq", where);
  if (!st) return std::move(st).error();
  st->bind_u64(1, after);
  for (;;) {
    const int rc = st->step();
    if (rc == SQLITE_DONE) break;
    if (rc != SQLITE_ROW) return sqlite_error(db, rc, where, "reading events");
    const std::uint64_t seq = st->u64(0);
    if (until != 0 && seq > until) break;
    if (seq != expect) {
      out.bad_seq = expect;
      out.bad_reason = "missing (the next stored event is " + std::to_string(seq) + ")";
      break;
    }
    const auto rec = st->blob(3);
    if (rec.size() > server_core::kMaxRecordBytes + 12) {
      out.bad_seq = seq;
      out.bad_reason = "record of " + std::to_string(rec.size()) + " bytes is too large";
      break;
    }
    buf.resize(header);
    buf.insert(buf.end(), rec.begin(), rec.end());
    auto log = server_core::read_stroke_log(buf);
    std::string why;
    if (!log) {
      why = log.error().message;
    } else if (log->tail) {
      why = log->tail->reason;
    } else if (log->events.size() != 1) {
      why = std::to_string(log->events.size()) + " events in one record";
    } else if (log->events[0].stroke_id != st->u64(1) ||
               static_cast<std::int64_t>(log->events[0].kind) != st->i64(2)) {
      why = "stroke or kind differ from the record's";
    }
    if (!why.empty()) {
      out.bad_seq = seq;
      out.bad_reason = why;
      break;
    }
    out.max_stroke_id = std::max(out.max_stroke_id, log->events[0].stroke_id);
    log->events[0].artist = st->u64(4);
    log->events[0].time_ms = st->i64(5);
    out.events.push_back(std::move(log->events[0]));
    ++expect;
  }
  return out;
}

Result<StoredHistory> read_history(const std::string& db_path, std::uint64_t until_seq) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(db_path, ec))
    return Error{Errc::not_found, "no canvas database " + db_path};
  const std::string where = "canvas database " + db_path;
  sqlite3* raw = nullptr;
  const int rc = sqlite3_open_v2(db_path.c_str(), &raw, SQLITE_OPEN_READONLY, nullptr);
  detail::Db db(raw);
  if (rc != SQLITE_OK) return detail::sqlite_error(raw, rc, where, "open");
  sqlite3_busy_timeout(raw, 5000);
  auto meta = detail::read_meta(raw, where);
  if (!meta) {
    if (meta.error().message.find("no such table") != std::string::npos)
      return Error{Errc::malformed, where + ": not a canvas database"};
    return std::move(meta).error();
  }
  if (meta->format_version != std::to_string(kStoreFormatVersion))
    return Error{Errc::unsupported,
                 where + ": format version '" + meta->format_version.substr(0, 40) + "'"};
  StoredHistory out;
  auto cfg = detail::config_from_meta(*meta, where);
  if (!cfg) return std::move(cfg).error();
  out.config = *cfg;
  auto scan = detail::scan_events(raw, where, 0, until_seq);
  if (!scan) return std::move(scan).error();
  if (scan->bad_seq != 0)
    return Error{Errc::malformed,
                 where + ": event " + std::to_string(scan->bad_seq) + ": " + scan->bad_reason};
  out.events = std::move(scan->events);
  return out;
}

}  // namespace deepcanvas::storage
