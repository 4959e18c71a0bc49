// CanvasStore::load(): the newest usable checkpoint (checked blob by blob, then restored), the
// events after it (each record decoded and checked), salvage. The contract: canvas_store.hpp.
#include <zstd.h>

#include <algorithm>

#include "deepcanvas/base/log.hpp"
#include "store_impl.hpp"

namespace deepcanvas::storage {

using server_core::BlockId;
using server_core::Octree;
using server_core::StrokeEvent;

namespace {

struct CheckpointRow {
  std::uint64_t id = 0, event_seq = 0, next_stroke = 0, block_count = 0;
  std::vector<std::uint8_t> allocator;
  std::uint64_t allocator_checksum = 0;
};

// The most bytes an uncompressed block may have (save_block's layout, octree.hpp).
std::size_t block_bytes(std::uint32_t cells) {
  return 32 + std::size_t{cells} * 8 + std::size_t{cells / 8} * 5;
}

// The stroke names (artist, handle, stroke, ended) that `sql` selects, its one parameter bound
// to `param`, appended to `out`.
Result<void> read_stroke_names(sqlite3* db, const char* sql, std::uint64_t param,
                               const std::string& where,
                               std::vector<server_core::StrokeName>& out) {
  auto st = detail::Stmt::prepare(db, sql, where);
  if (!st) return std::move(st).error();
  st->bind_u64(1, param);
  int rc = SQLITE_ROW;
  while ((rc = st->step()) == SQLITE_ROW)
    out.push_back({st->u64(0), st->u64(1), st->u64(2), st->u64(3) == detail::kNameStopped});
  if (rc != SQLITE_DONE) return detail::sqlite_error(db, rc, where, "reading stroke names");
  return {};
}

// Reads, checks and restores checkpoint `c`; an error names what is wrong with it.
Result<std::unique_ptr<Octree>> restore_checkpoint(sqlite3* db, const std::string& where,
                                                   const server_core::OctreeConfig& config,
                                                   const CheckpointRow& c) {
  const auto bad = [](std::string why) { return Error{Errc::malformed, std::move(why)}; };
  if (server_core::fnv1a64(c.allocator) != c.allocator_checksum) {
    return bad("allocator: checksum mismatch");
  }
  const std::uint64_t max_blocks =
      config.block_cells ? config.max_cells / config.block_cells + 1 : 0;
  if (c.block_count == 0 || c.block_count > max_blocks) {
    return bad("block count " + std::to_string(c.block_count) + " outside the canvas's capacity");
  }
  const std::size_t want = block_bytes(config.block_cells);
  std::vector<std::vector<std::uint8_t>> blocks(c.block_count);
  // For each block the newest row at or before this checkpoint.
  auto st = detail::Stmt::prepare(
      db, "SELECT block, checkpoint, data, checksum FROM checkpoint_blocks "
          "WHERE checkpoint <= ? AND block < ? ORDER BY block, checkpoint DESC",
      where);
  if (!st) return std::move(st).error();
  st->bind_u64(1, c.id);
  st->bind_u64(2, c.block_count);
  std::unique_ptr<ZSTD_DCtx, decltype(&ZSTD_freeDCtx)> dctx(ZSTD_createDCtx(), ZSTD_freeDCtx);
  if (!dctx) return Error{Errc::out_of_memory, "zstd: out of memory"};
  std::int64_t last_block = -1;
  for (;;) {
    const int rc = st->step();
    if (rc == SQLITE_DONE) break;
    if (rc != SQLITE_ROW) return detail::sqlite_error(db, rc, where, "reading checkpoint blocks");
    const std::int64_t b = st->i64(0);
    if (b == last_block) continue;  // an older row of the same block
    last_block = b;
    if (b < 0 || static_cast<std::uint64_t>(b) >= c.block_count) continue;
    const std::string name = "block " + std::to_string(b) + " (of checkpoint " +
                             std::to_string(st->i64(1)) + ")";
    const auto data = st->blob(2);
    const unsigned long long size = ZSTD_getFrameContentSize(data.data(), data.size());
    if (data.empty() || size == ZSTD_CONTENTSIZE_ERROR || size == ZSTD_CONTENTSIZE_UNKNOWN) {
      return bad(name + ": not a zstd frame");
    }
    if (size == 0 || size > want) {
      return bad(name + ": " + std::to_string(size) + " bytes, expected " + std::to_string(want));
    }
    auto& out = blocks[static_cast<std::size_t>(b)];
    out.resize(static_cast<std::size_t>(size));
    const std::size_t n =
        ZSTD_decompressDCtx(dctx.get(), out.data(), out.size(), data.data(), data.size());
    if (ZSTD_isError(n) || n != out.size()) {
      return bad(name + ": does not decompress" +
                 (ZSTD_isError(n) ? std::string(" (") + ZSTD_getErrorName(n) + ")" : ""));
    }
    if (server_core::fnv1a64(out) != st->u64(3)) return bad(name + ": checksum mismatch");
  }
  for (std::size_t b = 0; b < blocks.size(); ++b) {
    if (blocks[b].empty()) return bad("block " + std::to_string(b) + ": missing");
  }
  auto tree = Octree::restore(config, c.allocator, [&](BlockId b) -> std::span<const std::uint8_t> {
    if (b >= blocks.size()) return {};
    return blocks[b];
  });
  if (!tree) return bad("restore: " + tree.error().message);
  return tree;
}

}  // namespace

Result<LoadedCanvas> CanvasStore::load(bool salvage) {
  Impl& s = *impl_;
  sqlite3* db = s.db.get();
  const std::string& where = s.where;
  {
    std::lock_guard lock(s.mutex);
    if (s.writer.joinable() || s.stopping || s.closed || s.loaded) {
      return Error{Errc::internal, where + ": load() is called once, before start()"};
    }
  }
  LoadedCanvas out;
  out.config = s.config;

  // ---- the newest checkpoint that checks out ----
  std::vector<CheckpointRow> rows;
  {
    auto st = detail::Stmt::prepare(
        db, "SELECT id, event_seq, next_stroke, block_count, allocator, allocator_checksum "
            "FROM checkpoints ORDER BY id DESC",
        where);
    if (!st) return std::move(st).error();
    for (;;) {
      const int rc = st->step();
      if (rc == SQLITE_DONE) break;
      if (rc != SQLITE_ROW) return detail::sqlite_error(db, rc, where, "reading checkpoints");
      CheckpointRow r;
      r.id = st->u64(0);
      r.event_seq = st->u64(1);
      r.next_stroke = st->u64(2);
      r.block_count = st->u64(3);
      const auto a = st->blob(4);
      // An allocator is a few hundred bytes plus 4 per block.
      if (a.size() <= 512 + 4 * r.block_count) r.allocator.assign(a.begin(), a.end());
      r.allocator_checksum = st->u64(5);
      rows.push_back(std::move(r));
    }
  }
  std::size_t chosen = rows.size();
  for (std::size_t i = 0; i < rows.size(); ++i) {
    auto tree = restore_checkpoint(db, where, s.config, rows[i]);
    if (tree) {
      out.tree = std::move(*tree);
      chosen = i;
      break;
    }
    if (tree.error().code != Errc::malformed && tree.error().code != Errc::unsupported) {
      return std::move(tree).error();  // a read error: not the checkpoint's fault
    }
    const std::string next = i + 1 < rows.size()
                                 ? "falling back to checkpoint " + std::to_string(rows[i + 1].id)
                                 : "falling back to the events alone";
    out.notes.push_back("checkpoint " + std::to_string(rows[i].id) + " of " + where + ": " +
                        tree.error().message + "; " + next);
    base::log_event(base::LogLevel::warn, "storage_checkpoint_skipped",
                    {{"canvas", s.name}, {"path", s.path}, {"checkpoint", rows[i].id},
                     {"error", tree.error().message}});
  }
  if (chosen > 0) {
    // Bad checkpoints go, so that the incremental rule never picks their rows again (the
    // events, the history, stay; the next checkpoint is written from the replayed tree).
    const std::uint64_t keep = chosen < rows.size() ? rows[chosen].id : 0;
    if (auto r = detail::exec(db, "BEGIN IMMEDIATE", where); !r) return std::move(r).error();
    const std::string k = std::to_string(keep);
    const std::string sql = "DELETE FROM checkpoint_blocks WHERE checkpoint > " + k +
                            "; DELETE FROM checkpoints WHERE id > " + k + "; COMMIT";
    if (auto r = detail::exec(db, sql.c_str(), where); !r) {
      (void)detail::exec(db, "ROLLBACK", where);
      return std::move(r).error();
    }
    out.notes.push_back("removed " + std::to_string(chosen) + " unusable checkpoint(s) of " +
                        where);
  }
  if (out.tree) {
    const auto& c = rows[chosen];
    out.checkpoint_id = c.id;
    out.checkpoint_event_seq = c.event_seq;
    out.next_stroke_id = std::max<std::uint64_t>(1, c.next_stroke);
    s.covered.assign(c.block_count, true);
    auto st = detail::Stmt::prepare(
        db, "SELECT data, checksum FROM checkpoint_undo WHERE checkpoint = ?", where);
    if (!st) return std::move(st).error();
    st->bind_u64(1, c.id);
    if (st->step() == SQLITE_ROW) {
      const auto data = st->blob(0);
      if (server_core::fnv1a64(data) == st->u64(1))
        out.undo_history.assign(data.begin(), data.end());
      else
        out.notes.push_back("checkpoint " + std::to_string(c.id) + " of " + where +
                            ": its undo history does not check out (checksum); undo starts "
                            "with the strokes after it");
    }
  } else {
    auto fresh = Octree::create(s.config);
    if (!fresh) {
      return Error{fresh.error().code, where + ": the stored octree config: " +
                                           fresh.error().message};
    }
    out.tree = std::move(*fresh);
    s.covered.clear();
  }

  // ---- the events after it ----
  auto scan = detail::scan_events(db, where, out.checkpoint_event_seq, 0);
  if (!scan) return std::move(scan).error();
  out.events_after = std::move(scan->events);
  if (!out.events_after.empty())
    out.next_stroke_id = std::max(out.next_stroke_id, scan->max_stroke_id + 1);
  const std::uint64_t bad_seq = scan->bad_seq;
  const std::string bad_reason = scan->bad_reason;
  if (bad_seq != 0) {
    const std::uint64_t good = bad_seq - 1;
    if (!salvage) {
      return Error{Errc::malformed, where + ": event " + std::to_string(bad_seq) + ": " +
                                        bad_reason + "; start with --salvage to keep the " +
                                        std::to_string(good) + " events before it"};
    }
    std::uint64_t dropped = 0;
    {
      auto st = detail::Stmt::prepare(db, "SELECT count(*) FROM events WHERE seq >= ?", where);
      if (!st) return std::move(st).error();
      st->bind_u64(1, bad_seq);
      if (st->step() == SQLITE_ROW) dropped = st->u64(0);
    }
    // The strokes whose end goes with the dropped events are no longer ended (stroke_names).
    const std::string from = std::to_string(bad_seq);
    const std::string sql =
        "BEGIN IMMEDIATE; UPDATE stroke_names SET ended = 0 WHERE stroke IN (SELECT stroke FROM "
        "events WHERE seq >= " + from + " AND kind = 3); DELETE FROM events WHERE seq >= " + from +
        "; COMMIT";
    if (auto r = detail::exec(db, sql.c_str(), where); !r) {
      (void)detail::exec(db, "ROLLBACK", where);
      return std::move(r).error();
    }
    out.notes.push_back("salvage: " + where + ": event " + std::to_string(bad_seq) + ": " +
                        bad_reason + "; dropped " + std::to_string(dropped) +
                        " events from it on, kept the " + std::to_string(good) + " before it");
    base::log_event(base::LogLevel::warn, "storage_salvaged",
                    {{"canvas", s.name}, {"path", s.path}, {"bad_seq", bad_seq},
                     {"dropped", dropped}, {"reason", bad_reason}});
  }
  out.last_seq = out.checkpoint_event_seq + out.events_after.size();
  // The newest names of ended strokes (stroke_names).
  if (auto r = read_stroke_names(db,
                                 "SELECT artist, handle, stroke, ended FROM stroke_names WHERE "
                                 "ended IN (1, 2) ORDER BY stroke DESC LIMIT ?",
                                 kMaxLoadedStrokeNames, where, out.stroke_names);
      !r)
    return std::move(r).error();
  // The newest unended names (unended_names), oldest of them first.
  if (auto r = read_stroke_names(db,
                                 "SELECT artist, handle, stroke, ended FROM (SELECT artist, handle, "
                                 "stroke, ended FROM stroke_names WHERE ended = 0 ORDER BY stroke "
                                 "DESC LIMIT ?) ORDER BY stroke",
                                 kMaxLoadedStrokeNames, where, out.unended_names);
      !r)
    return std::move(r).error();
  {
    std::lock_guard lock(s.mutex);
    s.last_seq = s.durable_seq = out.last_seq;
    s.checkpoint_seq = out.checkpoint_event_seq;
    // A restore that replayed events wants a checkpoint at once, so that the next restart
    // does not replay them again (and more): after repeated crashes the replay would grow.
    s.checkpoint_time = std::chrono::steady_clock::now();
    if (!out.events_after.empty()) s.checkpoint_time -= s.options.checkpoint_every;
    s.loaded = true;
  }
  return out;
}

}  // namespace deepcanvas::storage
