// CanvasStore: writing a checkpoint on the writer thread (compression in chunks with event
// commits in between, then one transaction). The contract: canvas_store.hpp.
#include <zstd.h>

#include <chrono>
#include <memory>

#include "deepcanvas/base/log.hpp"
#include "store_impl.hpp"

namespace deepcanvas::storage {

using server_core::CheckpointData;

namespace {

constexpr std::size_t kBlocksPerChunk = 8;  // events are committed between chunks

struct PackedBlock {
  server_core::BlockId block = 0;
  std::uint64_t version = 0;
  std::uint64_t checksum = 0;
  std::vector<std::uint8_t> data;
};

struct CctxFree {
  void operator()(ZSTD_CCtx* c) const noexcept { ZSTD_freeCCtx(c); }
};

}  // namespace

void CanvasStore::Impl::write_checkpoint(CheckpointData data) {
  using clock = std::chrono::steady_clock;
  const auto t0 = clock::now();
  if (parked) {
    data = detail::merge_checkpoints(std::move(*parked), std::move(data));
    parked.reset();
  }
  const auto give_up = [&](const std::string& why, bool keep) {
    ++checkpoints_failed;
    base::log_event(base::LogLevel::error, "storage_checkpoint_failed",
                    {{"canvas", name}, {"path", path}, {"event_seq", data.event_seq},
                     {"blocks", data.blocks.size()}, {"kept", keep}, {"error", why}});
    if (keep) parked = std::move(data);
  };

  // The events the checkpoint contains must be durable before it is: commit them first.
  write_pending();

  std::unique_ptr<ZSTD_CCtx, CctxFree> cctx(ZSTD_createCCtx());
  if (!cctx) return give_up("zstd: out of memory", true);
  std::vector<PackedBlock> packed;
  packed.reserve(data.blocks.size());
  std::uint64_t bytes = data.allocator.size();
  for (std::size_t i = 0; i < data.blocks.size(); ++i) {
    const auto& b = data.blocks[i];
    PackedBlock p;
    p.block = b.block;
    p.version = b.version;
    p.checksum = server_core::fnv1a64(b.bytes);
    p.data.resize(ZSTD_compressBound(b.bytes.size()));
    const std::size_t n = ZSTD_compressCCtx(cctx.get(), p.data.data(), p.data.size(),
                                            b.bytes.data(), b.bytes.size(), options.zstd_level);
    if (ZSTD_isError(n)) {
      return give_up(std::string("zstd: ") + ZSTD_getErrorName(n), true);
    }
    p.data.resize(n);
    bytes += n;
    packed.push_back(std::move(p));
    // Strokes acked meanwhile do not wait for the whole compression.
    if ((i + 1) % kBlocksPerChunk == 0) write_pending();
  }

  std::uint64_t durable = 0;
  {
    std::lock_guard lock(mutex);
    durable = durable_seq;
  }
  if (data.event_seq > durable) {
    return give_up("its events (up to " + std::to_string(data.event_seq) +
                       ") are not durable yet (durable: " + std::to_string(durable) + ")",
                   true);
  }

  // The incremental rule needs a row for every block below block_count.
  std::vector<bool> now_covered = covered;
  if (now_covered.size() < data.block_count) now_covered.resize(data.block_count, false);
  for (const auto& p : packed) {
    if (p.block < now_covered.size()) now_covered[p.block] = true;
  }
  for (std::uint32_t b = 0; b < data.block_count; ++b) {
    if (!now_covered[b]) {
      return give_up("block " + std::to_string(b) +
                         " has never been saved and is not in this checkpoint (a first "
                         "checkpoint must hold every block)",
                     false);
    }
  }

  if (options.before_write) {
    if (auto r = options.before_write(); !r) return give_up(r.error().message, true);
  }
  sqlite3* h = db.get();
  if (auto r = detail::exec(h, "BEGIN IMMEDIATE", where); !r) {
    return give_up(r.error().message, true);
  }
  const auto fail = [&](int rc, const char* what) {
    Error e = detail::sqlite_error(h, rc, where, what);
    (void)detail::exec(h, "ROLLBACK", where);
    give_up(e.message, true);
  };
  auto& cs = insert_checkpoint;
  cs.reset();
  cs.bind_u64(1, data.event_seq);
  cs.bind_u64(2, data.next_stroke_id);
  cs.bind(3, data.block_count);
  cs.bind(4, detail::now_unix_ms());
  cs.bind_blob(5, data.allocator);
  cs.bind_u64(6, server_core::fnv1a64(data.allocator));
  cs.bind(7, static_cast<std::int64_t>(packed.size()));
  int rc = cs.step();
  cs.reset();
  if (rc != SQLITE_DONE) return fail(rc, "writing a checkpoint");
  const std::int64_t id = sqlite3_last_insert_rowid(h);
  if (!data.undo_history.empty()) {
    auto& us = insert_undo;
    us.reset();
    us.bind(1, id);
    us.bind_blob(2, data.undo_history);
    us.bind_u64(3, server_core::fnv1a64(data.undo_history));
    rc = us.step();
    us.reset();
    if (rc != SQLITE_DONE) return fail(rc, "writing a checkpoint's undo history");
  }
  auto& bs = insert_block;
  for (const auto& p : packed) {
    bs.reset();
    bs.bind(1, id);
    bs.bind(2, p.block);
    bs.bind_u64(3, p.version);
    bs.bind_blob(4, p.data);
    bs.bind_u64(5, p.checksum);
    rc = bs.step();
    bs.reset();
    if (rc != SQLITE_DONE) return fail(rc, "writing checkpoint blocks");
  }
  // Two usable checkpoints are kept: this one and the one before it (the fallback when this
  // one does not read back). A block's rows older than its newest row at or before the previous
  // checkpoint serve neither, and go with the checkpoints before the previous one; the history
  // (events) is never pruned, so older states are rebuilt from it (replay --until).
  {
    const std::string prev = "(SELECT max(id) FROM checkpoints WHERE id < " + std::to_string(id) + ")";
    const std::string prune =
        "DELETE FROM checkpoint_blocks WHERE checkpoint < " + prev +
        " AND EXISTS (SELECT 1 FROM checkpoint_blocks AS n WHERE n.block = "
        "checkpoint_blocks.block AND n.checkpoint > checkpoint_blocks.checkpoint AND "
        "n.checkpoint <= " + prev + "); DELETE FROM checkpoints WHERE id < " + prev +
        "; DELETE FROM checkpoint_undo WHERE checkpoint < " + prev + ";";
    rc = sqlite3_exec(h, prune.c_str(), nullptr, nullptr, nullptr);
    if (rc != SQLITE_OK) return fail(rc, "pruning older checkpoints");
  }
  rc = sqlite3_exec(h, "COMMIT", nullptr, nullptr, nullptr);
  if (rc != SQLITE_OK) return fail(rc, "committing a checkpoint");

  covered = std::move(now_covered);
  ++checkpoints_written;
  const auto ms =
      std::chrono::duration_cast<std::chrono::milliseconds>(clock::now() - t0).count();
  base::log_event(base::LogLevel::info, "storage_checkpoint",
                  {{"canvas", name}, {"checkpoint", id}, {"event_seq", data.event_seq},
                   {"blocks", packed.size()}, {"block_count", data.block_count},
                   {"bytes", bytes}, {"ms", ms}});
}

}  // namespace deepcanvas::storage
