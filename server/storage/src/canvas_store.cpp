// CanvasStore: open (schema, format version, config), the journal's queue and the writer thread
// (group commit, failure and recovery). Checkpoint writes: store_checkpoint.cpp; load():
// store_load.cpp. The contract: canvas_store.hpp.
#include <algorithm>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <system_error>

#include "deepcanvas/base/log.hpp"
#include "deepcanvas/base/thread_name.hpp"
#include "store_impl.hpp"

namespace deepcanvas::storage {

using server_core::CheckpointData;
using server_core::OctreeConfig;

namespace detail {

std::int64_t now_unix_ms() noexcept {
  return std::chrono::duration_cast<std::chrono::milliseconds>(
             std::chrono::system_clock::now().time_since_epoch())
      .count();
}

std::string describe(const std::string& canvas, const std::string& path) {
  return "canvas '" + canvas + "' (" + path + ")";
}

namespace {

template <class T>
bool parse_int(const std::string& s, T& out) {
  const char* b = s.data();
  const char* e = b + s.size();
  auto r = std::from_chars(b, e, out);
  return r.ec == std::errc() && r.ptr == e;
}

}  // namespace

Result<OctreeConfig> config_from_meta(const MetaValues& m, const std::string& where) {
  OctreeConfig c;
  const auto bad = [&](const char* key) {
    return Error{Errc::malformed, where + ": meta '" + key + "' is missing or not a number"};
  };
  if (!parse_int(m.roots_per_axis, c.roots_per_axis)) return bad("roots_per_axis");
  if (!parse_int(m.max_depth, c.max_depth)) return bad("max_depth");
  if (!parse_int(m.block_cells, c.block_cells)) return bad("block_cells");
  if (!parse_int(m.max_cells, c.max_cells)) return bad("max_cells");
  char* end = nullptr;
  errno = 0;
  c.edge_m = m.edge_m.empty() ? NAN : std::strtod(m.edge_m.c_str(), &end);
  if (m.edge_m.empty() || errno != 0 || end != m.edge_m.c_str() + m.edge_m.size() ||
      !std::isfinite(c.edge_m)) {
    return bad("edge_m");
  }
  return c;
}

CheckpointData merge_checkpoints(CheckpointData older, CheckpointData newer) {
  std::map<server_core::BlockId, std::size_t> have;
  for (std::size_t i = 0; i < newer.blocks.size(); ++i) have[newer.blocks[i].block] = i;
  for (auto& b : older.blocks) {
    if (b.block >= newer.block_count || have.count(b.block)) continue;
    have[b.block] = newer.blocks.size();
    newer.blocks.push_back(std::move(b));
  }
  return newer;
}

}  // namespace detail

namespace {

constexpr const char* kSchema = R"sql(
CREATE TABLE IF NOT EXISTS meta(key TEXT PRIMARY KEY, value);
CREATE TABLE IF NOT EXISTS artists(artist INTEGER PRIMARY KEY, role TEXT, name TEXT,
                                   first_seen_ms INTEGER);
CREATE TABLE IF NOT EXISTS events(seq INTEGER PRIMARY KEY, stroke INTEGER NOT NULL,
                                  kind INTEGER NOT NULL, artist INTEGER NOT NULL,
                                  time_ms INTEGER NOT NULL, record BLOB NOT NULL);
CREATE TABLE IF NOT EXISTS checkpoints(id INTEGER PRIMARY KEY, event_seq INTEGER NOT NULL,
                                       next_stroke INTEGER NOT NULL,
                                       block_count INTEGER NOT NULL, created_ms INTEGER,
                                       allocator BLOB NOT NULL,
                                       allocator_checksum INTEGER NOT NULL,
                                       blocks_written INTEGER);
CREATE TABLE IF NOT EXISTS checkpoint_blocks(checkpoint INTEGER NOT NULL, block INTEGER NOT NULL,
                                             version INTEGER NOT NULL, data BLOB NOT NULL,
                                             checksum INTEGER NOT NULL,
                                             PRIMARY KEY(checkpoint, block));
CREATE INDEX IF NOT EXISTS checkpoint_blocks_by_block ON checkpoint_blocks(block, checkpoint);
CREATE TABLE IF NOT EXISTS checkpoint_undo(checkpoint INTEGER PRIMARY KEY, data BLOB NOT NULL,
                                           checksum INTEGER NOT NULL);
CREATE TABLE IF NOT EXISTS stroke_names(stroke INTEGER PRIMARY KEY, artist INTEGER NOT NULL,
                                        handle INTEGER NOT NULL, ended INTEGER NOT NULL);
)sql";

bool plain_name(const std::string& n) {
  if (n.empty() || n.size() > 200 || n == "." || n == "..") return false;
  for (char ch : n) {
    if (ch == '/' || ch == '\0' || static_cast<unsigned char>(ch) < 0x20) return false;
  }
  return true;
}

std::string num(double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.17g", v);
  return buf;
}

Result<void> create_schema(sqlite3* db, const std::string& where, const std::string& name,
                           const OctreeConfig& c) {
  if (auto r = detail::exec(db, "BEGIN IMMEDIATE", where); !r) return r;
  auto fail = [&](Result<void> r) {
    (void)detail::exec(db, "ROLLBACK", where);
    return r;
  };
  if (auto r = detail::exec(db, kSchema, where); !r) return fail(std::move(r));
  auto st = detail::Stmt::prepare(db, "INSERT OR REPLACE INTO meta(key, value) VALUES(?, ?)",
                                  where);
  if (!st) return fail(std::move(st).error());
  const std::pair<const char*, std::string> rows[] = {
      {"format_version", std::to_string(kStoreFormatVersion)},
      {"canvas", name},
      {"created_ms", std::to_string(detail::now_unix_ms())},
      {"roots_per_axis", std::to_string(c.roots_per_axis)},
      {"edge_m", num(c.edge_m)},
      {"max_depth", std::to_string(c.max_depth)},
      {"block_cells", std::to_string(c.block_cells)},
      {"max_cells", std::to_string(c.max_cells)},
  };
  for (const auto& [k, v] : rows) {
    st->reset();
    st->bind_text(1, k);
    st->bind_text(2, v);
    const int rc = st->step();
    if (rc != SQLITE_DONE) return fail(detail::sqlite_error(db, rc, where, "writing meta"));
  }
  st->finalize();
  return detail::exec(db, "COMMIT", where);
}

}  // namespace

CanvasStore::CanvasStore(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}

CanvasStore::~CanvasStore() { close(); }

Result<std::unique_ptr<CanvasStore>> CanvasStore::open(const std::string& dir,
                                                       const std::string& name,
                                                       const OctreeConfig& config_for_new,
                                                       const StoreOptions& options) {
  if (!plain_name(name)) {
    return Error{Errc::invalid_argument, "canvas name '" + name + "' is not a plain file name"};
  }
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) {
    return Error{Errc::io_error, "cannot create data directory " + dir + ": " + ec.message()};
  }
  auto impl = std::make_unique<Impl>();
  impl->name = name;
  impl->path = (std::filesystem::path(dir) / (name + kCanvasFileSuffix)).string();
  impl->where = detail::describe(name, impl->path);
  impl->options = options;
  impl->options.zstd_level = std::clamp(options.zstd_level, 1, 3);
  const std::string& where = impl->where;

  sqlite3* raw = nullptr;
  int rc = sqlite3_open_v2(impl->path.c_str(), &raw, SQLITE_OPEN_READWRITE | SQLITE_OPEN_CREATE,
                           nullptr);
  impl->db = detail::Db(raw);
  if (rc != SQLITE_OK) return detail::sqlite_error(raw, rc, where, "open");
  sqlite3* db = impl->db.get();
  sqlite3_extended_result_codes(db, 1);
  sqlite3_busy_timeout(db, static_cast<int>(options.busy_timeout.count()));

  // Is it a canvas database, and of which version? (Reading the schema also tells a file that
  // is not SQLite at all: SQLITE_NOTADB.)
  bool has_meta = false;
  {
    auto st = detail::Stmt::prepare(
        db, "SELECT count(*) FROM sqlite_master WHERE type='table' AND name='meta'", where);
    if (!st) return std::move(st).error();
    rc = st->step();
    if (rc != SQLITE_ROW) return detail::sqlite_error(db, rc, where, "reading the schema");
    has_meta = st->i64(0) > 0;
  }
  if (has_meta) {
    auto meta = detail::read_meta(db, where);
    if (!meta) return std::move(meta).error();
    std::uint32_t version = 0;
    const auto& v = meta->format_version;
    auto pr = std::from_chars(v.data(), v.data() + v.size(), version);
    if (pr.ec != std::errc() || pr.ptr != v.data() + v.size()) {
      return Error{Errc::unsupported,
                   where + ": unreadable format version '" + v.substr(0, 40) + "'"};
    }
    if (version != kStoreFormatVersion) {
      return Error{Errc::unsupported, where + ": format version " + std::to_string(version) +
                                          " (this build reads version " +
                                          std::to_string(kStoreFormatVersion) + ")"};
    }
    auto cfg = detail::config_from_meta(*meta, where);
    if (!cfg) return std::move(cfg).error();
    impl->config = *cfg;
  } else {
    // A non-empty database without our meta table is someone else's file.
    auto st = detail::Stmt::prepare(db, "SELECT count(*) FROM sqlite_master", where);
    if (!st) return std::move(st).error();
    rc = st->step();
    if (rc != SQLITE_ROW) return detail::sqlite_error(db, rc, where, "reading the schema");
    if (st->i64(0) > 0) return Error{Errc::malformed, where + ": not a canvas database"};
    impl->config = config_for_new;
    impl->created = true;
  }

  // WAL: one sync per commit, readers (tools) never block the writer.
  {
    auto st = detail::Stmt::prepare(db, "PRAGMA journal_mode=WAL", where);
    if (!st) return std::move(st).error();
    rc = st->step();
    if (rc != SQLITE_ROW || st->text(0) != "wal") {
      return Error{Errc::io_error, where + ": cannot switch to WAL journal mode"};
    }
  }
  if (auto r = detail::exec(db, options.sync ? "PRAGMA synchronous=FULL" : "PRAGMA synchronous=OFF",
                            where);
      !r) {
    return std::move(r).error();
  }
  if (!has_meta) {
    if (auto r = create_schema(db, where, name, impl->config); !r) return std::move(r).error();
  } else {
    if (auto r = detail::exec(db, kSchema, where); !r) return std::move(r).error();
  }

  // The history so far: sequence numbers continue from the last stored event.
  {
    auto st = detail::Stmt::prepare(
        db, "SELECT (SELECT ifnull(max(seq), 0) FROM events), "
            "(SELECT ifnull(max(event_seq), 0) FROM checkpoints)",
        where);
    if (!st) return std::move(st).error();
    rc = st->step();
    if (rc != SQLITE_ROW) return detail::sqlite_error(db, rc, where, "reading events");
    impl->last_seq = impl->durable_seq = st->i64(0) > 0 ? st->u64(0) : 0;
    impl->checkpoint_seq = st->i64(1) > 0 ? st->u64(1) : 0;
  }
  if (auto r = impl->prepare_statements(); !r) return std::move(r).error();
  return std::unique_ptr<CanvasStore>(new CanvasStore(std::move(impl)));
}

Result<void> CanvasStore::Impl::prepare_statements() {
  sqlite3* h = db.get();
  auto a = detail::Stmt::prepare(
      h, "INSERT INTO events(seq, stroke, kind, artist, time_ms, record) VALUES(?,?,?,?,?,?)",
      where);
  if (!a) return std::move(a).error();
  auto b = detail::Stmt::prepare(
      h, "INSERT INTO artists(artist, role, name, first_seen_ms) VALUES(?,?,?,?) "
         "ON CONFLICT(artist) DO UPDATE SET role=excluded.role, name=excluded.name",
      where);
  if (!b) return std::move(b).error();
  auto c = detail::Stmt::prepare(
      h, "INSERT INTO checkpoints(event_seq, next_stroke, block_count, created_ms, allocator, "
         "allocator_checksum, blocks_written) VALUES(?,?,?,?,?,?,?)",
      where);
  if (!c) return std::move(c).error();
  auto d = detail::Stmt::prepare(
      h, "INSERT INTO checkpoint_blocks(checkpoint, block, version, data, checksum) "
         "VALUES(?,?,?,?,?)",
      where);
  if (!d) return std::move(d).error();
  auto u = detail::Stmt::prepare(
      h, "INSERT OR REPLACE INTO checkpoint_undo(checkpoint, data, checksum) VALUES(?,?,?)", where);
  if (!u) return std::move(u).error();
  auto n = detail::Stmt::prepare(
      h, "INSERT OR REPLACE INTO stroke_names(stroke, artist, handle, ended) VALUES(?,?,?,0)",
      where);
  if (!n) return std::move(n).error();
  // Only its sender's end (EndedBy::sender, EndedBy::stopped): the end of a stroke the server
  // cut short (its connection closed, the idle timeout; a restart's for one the stop cut off)
  // leaves the name unended, as the sender may not have what it sent after the cut painted.
  auto ne = detail::Stmt::prepare(
      h, "UPDATE stroke_names SET ended = ? WHERE stroke = ? AND artist = ?", where);
  if (!ne) return std::move(ne).error();
  insert_name = std::move(*n);
  end_name = std::move(*ne);
  insert_undo = std::move(*u);
  insert_event = std::move(*a);
  upsert_artist = std::move(*b);
  insert_checkpoint = std::move(*c);
  insert_block = std::move(*d);
  return {};
}

// ---- journal API ----

std::uint64_t CanvasStore::append(const server_core::StrokeEvent& event, std::uint64_t artist,
                                  server_core::EndedBy ended_by) {
  detail::PendingEvent p;
  switch (ended_by) {
    case server_core::EndedBy::sender:
      p.name_ended = detail::kNameEnded;
      break;
    case server_core::EndedBy::stopped:
      p.name_ended = detail::kNameStopped;
      break;
    case server_core::EndedBy::server:
      p.name_ended = detail::kNameUnended;
      break;
  }
  p.stroke = event.stroke_id;
  p.kind = static_cast<std::uint8_t>(event.kind);
  p.artist = artist;
  if (event.kind == server_core::StrokeEvent::Kind::begin && artist != 0) p.handle = event.handle;
  p.time_ms = detail::now_unix_ms();
  auto rec = server_core::encode_stroke_event(event);
  if (rec) {
    p.record = std::move(*rec);
  } else {
    // Cannot happen for events the painter took (a record's limit is far above a message's);
    // an end event keeps the history's order and stroke bookkeeping intact.
    base::log_event(base::LogLevel::error, "storage_event_too_large",
                    {{"canvas", impl_->name}, {"stroke", event.stroke_id},
                     {"error", rec.error().message}});
    server_core::StrokeEvent end;
    end.kind = server_core::StrokeEvent::Kind::end;
    end.stroke_id = event.stroke_id;
    p.kind = static_cast<std::uint8_t>(end.kind);
    p.record = std::move(*server_core::encode_stroke_event(end));
  }
  std::uint64_t seq = 0;
  {
    std::lock_guard lock(impl_->mutex);
    seq = ++impl_->last_seq;
    p.seq = seq;
    impl_->events.push_back(std::move(p));
  }
  impl_->wake.notify_one();
  return seq;
}

void CanvasStore::when_durable(std::uint64_t seq, std::function<void(Result<void>)> done) {
  {
    std::lock_guard lock(impl_->mutex);
    if (seq > impl_->durable_seq) {
      if (!impl_->closed) {
        impl_->waiters.emplace(seq, std::move(done));
        return;
      }
    } else {
      seq = 0;  // durable
    }
  }
  if (seq == 0) {
    done(Result<void>{});
  } else {
    done(Error{Errc::io_error, impl_->where + ": the store is closed; event " +
                                   std::to_string(seq) + " is not durable"});
  }
}

Result<void> CanvasStore::accepting() const {
  std::lock_guard lock(impl_->mutex);
  if (impl_->write_error) return *impl_->write_error;
  if (impl_->closed || impl_->stopping) {
    return Error{Errc::io_error, "canvas '" + impl_->name + "' storage is closed"};
  }
  return {};
}

bool CanvasStore::wants_checkpoint() {
  std::lock_guard lock(impl_->mutex);
  if (impl_->last_seq <= impl_->checkpoint_seq) return false;
  return impl_->last_seq - impl_->checkpoint_seq >= impl_->options.checkpoint_every_events ||
         std::chrono::steady_clock::now() - impl_->checkpoint_time >=
             impl_->options.checkpoint_every;
}

void CanvasStore::checkpoint(CheckpointData data) {
  {
    std::lock_guard lock(impl_->mutex);
    impl_->checkpoint_seq = std::max(impl_->checkpoint_seq, data.event_seq);
    impl_->checkpoint_time = std::chrono::steady_clock::now();
    if (impl_->checkpoint) {
      data = detail::merge_checkpoints(std::move(*impl_->checkpoint), std::move(data));
    }
    impl_->checkpoint = std::move(data);
  }
  impl_->wake.notify_one();
}

void CanvasStore::note_artist(const server_core::ArtistInfo& artist) {
  {
    std::lock_guard lock(impl_->mutex);
    auto& a = impl_->artists[artist.artist];
    a.info = artist;
    a.seen_ms = detail::now_unix_ms();
  }
  impl_->wake.notify_one();
}

const std::string& CanvasStore::name() const noexcept { return impl_->name; }
const std::string& CanvasStore::path() const noexcept { return impl_->path; }
const OctreeConfig& CanvasStore::config() const noexcept { return impl_->config; }
bool CanvasStore::created() const noexcept { return impl_->created; }
std::uint64_t CanvasStore::last_seq() const {
  std::lock_guard lock(impl_->mutex);
  return impl_->last_seq;
}
std::uint64_t CanvasStore::durable_seq() const {
  std::lock_guard lock(impl_->mutex);
  return impl_->durable_seq;
}
std::uint64_t CanvasStore::commits() const noexcept { return impl_->commits.load(); }
std::uint64_t CanvasStore::checkpoints_written() const noexcept {
  return impl_->checkpoints_written.load();
}
std::uint64_t CanvasStore::checkpoints_failed() const noexcept {
  return impl_->checkpoints_failed.load();
}

// ---- writer ----

void CanvasStore::start() {
  std::lock_guard lock(impl_->mutex);
  if (impl_->writer.joinable() || impl_->closed) return;
  impl_->writer = std::thread([impl = impl_.get()] {
    base::set_thread_name("canvas-store");
    impl->run();
  });
}

void CanvasStore::close() {
  if (!impl_) return;
  std::thread writer;
  {
    std::lock_guard lock(impl_->mutex);
    if (impl_->closed || impl_->stopping) return;  // closed, or closing on another thread
    impl_->stopping = true;
    writer = std::move(impl_->writer);
  }
  impl_->wake.notify_all();
  if (writer.joinable()) {
    writer.join();
  } else {
    impl_->run();  // never started: write what was queued here
  }
  std::multimap<std::uint64_t, std::function<void(Result<void>)>> left;
  {
    std::lock_guard lock(impl_->mutex);
    impl_->closed = true;
    left.swap(impl_->waiters);
  }
  for (auto& [seq, done] : left) {
    done(Error{Errc::io_error, impl_->where + ": closed with event " + std::to_string(seq) +
                                   " not durable"});
  }
  impl_->insert_event.finalize();
  impl_->upsert_artist.finalize();
  impl_->insert_checkpoint.finalize();
  impl_->insert_block.finalize();
  impl_->insert_undo.finalize();
  impl_->db.reset();
}

void CanvasStore::Impl::run() {
  using namespace std::chrono_literals;
  int close_tries = 0;
  for (;;) {
    std::optional<CheckpointData> ckpt;
    bool closing = false;  // `stopping` as read under the lock this round
    {
      std::unique_lock lock(mutex);
      const auto has_work = [&] {
        return !events.empty() || !artists.empty() || checkpoint.has_value();
      };
      if (write_error && !stopping) {
        wake.wait_for(lock, 200ms, [&] { return stopping; });
      } else {
        wake.wait(lock, [&] { return stopping || has_work(); });
      }
      if (stopping) {
        if (!has_work() && !parked) return;
        if (write_error) {
          // Closing while writes fail: a few more tries, then give up (close() reports).
          if (++close_tries > 10) return;
          lock.unlock();
          std::this_thread::sleep_for(100ms);
          lock.lock();
        }
      }
      if (checkpoint && !write_error) {
        ckpt = std::move(checkpoint);
        checkpoint.reset();
      }
      closing = stopping;
    }
    write_pending();
    if (ckpt) write_checkpoint(std::move(*ckpt));
    if (closing && parked) {
      // Nothing newer will come: one last try for the failed checkpoint.
      CheckpointData last = std::move(*parked);
      parked.reset();
      write_checkpoint(std::move(last));
      parked.reset();
    }
    if (closing) {
      std::lock_guard lock(mutex);
      if (events.empty() && artists.empty() && !checkpoint && !write_error) return;
    }
  }
}

bool CanvasStore::Impl::write_pending() {
  std::vector<detail::PendingEvent> batch;
  std::vector<detail::PendingArtist> artists_batch;
  {
    std::lock_guard lock(mutex);
    if (events.empty() && artists.empty()) return false;
    batch.reserve(events.size());
    for (auto& e : events) batch.push_back(std::move(e));
    events.clear();
    for (auto& [id, a] : artists) artists_batch.push_back(std::move(a));
    artists.clear();
  }
  auto r = write_batch(batch, artists_batch);
  if (r) {
    std::uint64_t up_to = 0;
    bool recovered = false;
    {
      std::lock_guard lock(mutex);
      if (!batch.empty()) {
        durable_seq = std::max(durable_seq, batch.back().seq);
        ++commits;
      }
      up_to = durable_seq;
      recovered = write_error.has_value();
      write_error.reset();
    }
    if (recovered) {
      base::log_event(base::LogLevel::warn, "storage_write_recovered",
                      {{"canvas", name}, {"path", path}, {"durable_seq", up_to}});
    }
    fire_durable(up_to);
    return true;
  }
  bool first = false;
  {
    std::lock_guard lock(mutex);
    // Put the batch back in front of what was queued meanwhile (order and seqs kept).
    for (auto it = batch.rbegin(); it != batch.rend(); ++it) events.push_front(std::move(*it));
    for (auto& a : artists_batch) artists.try_emplace(a.info.artist, std::move(a));
    first = !write_error.has_value();
    write_error = Error{Errc::io_error, "canvas '" + name + "' cannot store strokes: " +
                                            r.error().message +
                                            "; new strokes are refused until writes succeed "
                                            "again"};
  }
  if (first) {
    base::log_event(base::LogLevel::error, "storage_write_failed",
                    {{"canvas", name}, {"path", path}, {"error", r.error().message}});
  }
  return true;
}

Result<void> CanvasStore::Impl::write_batch(const std::vector<detail::PendingEvent>& batch,
                                            const std::vector<detail::PendingArtist>& arts) {
  if (options.before_write) {
    if (auto r = options.before_write(); !r) return r;
  }
  sqlite3* h = db.get();
  if (auto r = detail::exec(h, "BEGIN IMMEDIATE", where); !r) return r;
  const auto fail = [&](int rc, const char* what) -> Result<void> {
    Error e = detail::sqlite_error(h, rc, where, what);
    (void)detail::exec(h, "ROLLBACK", where);
    return e;
  };
  for (const auto& e : batch) {
    auto& st = insert_event;
    st.reset();
    st.bind_u64(1, e.seq);
    st.bind_u64(2, e.stroke);
    st.bind(3, e.kind);
    st.bind_u64(4, e.artist);
    st.bind(5, e.time_ms);
    st.bind_blob(6, e.record);
    const int rc = st.step();
    st.reset();
    if (rc != SQLITE_DONE) return fail(rc, "writing events");
    const auto kind = static_cast<server_core::StrokeEvent::Kind>(e.kind);
    if (kind == server_core::StrokeEvent::Kind::begin && e.handle != 0) {
      auto& n = insert_name;
      n.reset();
      n.bind_u64(1, e.stroke);
      n.bind_u64(2, e.artist);
      n.bind_u64(3, e.handle);
      const int nrc = n.step();
      n.reset();
      if (nrc != SQLITE_DONE) return fail(nrc, "writing stroke names");
    } else if (kind == server_core::StrokeEvent::Kind::end && e.artist != 0 &&
               e.name_ended != detail::kNameUnended) {
      auto& n = end_name;
      n.reset();
      n.bind_u64(1, static_cast<std::uint64_t>(e.name_ended));
      n.bind_u64(2, e.stroke);
      n.bind_u64(3, e.artist);
      const int nrc = n.step();
      n.reset();
      if (nrc != SQLITE_DONE) return fail(nrc, "writing stroke names");
    }
  }
  for (const auto& a : arts) {
    auto& st = upsert_artist;
    st.reset();
    st.bind_u64(1, a.info.artist);
    st.bind_text(2, a.info.role);
    st.bind_text(3, a.info.name);
    st.bind(4, a.seen_ms);
    const int rc = st.step();
    st.reset();
    if (rc != SQLITE_DONE) return fail(rc, "writing artists");
  }
  const int rc = sqlite3_exec(h, "COMMIT", nullptr, nullptr, nullptr);
  if (rc != SQLITE_OK) return fail(rc, "commit");
  return {};
}

void CanvasStore::Impl::fire_durable(std::uint64_t up_to) {
  std::vector<std::function<void(Result<void>)>> ready;
  {
    std::lock_guard lock(mutex);
    auto end = waiters.upper_bound(up_to);
    for (auto it = waiters.begin(); it != end; ++it) ready.push_back(std::move(it->second));
    waiters.erase(waiters.begin(), end);
  }
  for (auto& done : ready) done(Result<void>{});
}

}  // namespace deepcanvas::storage
