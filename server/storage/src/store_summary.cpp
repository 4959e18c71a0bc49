// summarize(): read-only statistics of a canvas database for tools; list_canvases() and
// DataDirLock. The contract: canvas_store.hpp.
#include <fcntl.h>
#include <sys/file.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <charconv>
#include <cstring>
#include <filesystem>
#include <map>
#include <system_error>

#include "store_impl.hpp"

namespace deepcanvas::storage {

namespace {

std::uint64_t file_size(const std::string& p) {
  std::error_code ec;
  const auto n = std::filesystem::file_size(p, ec);
  return ec ? 0 : static_cast<std::uint64_t>(n);
}

}  // namespace

Result<StoreSummary> summarize(const std::string& db_path) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(db_path, ec)) {
    return Error{Errc::not_found, "no canvas database " + db_path};
  }
  const std::string where = "canvas database " + db_path;
  sqlite3* raw = nullptr;
  int rc = sqlite3_open_v2(db_path.c_str(), &raw, SQLITE_OPEN_READONLY, nullptr);
  detail::Db db(raw);
  if (rc != SQLITE_OK) return detail::sqlite_error(raw, rc, where, "open");
  sqlite3_busy_timeout(raw, 5000);

  StoreSummary s;
  s.path = db_path;
  auto meta = detail::read_meta(raw, where);
  if (!meta) {
    if (meta.error().message.find("no such table") != std::string::npos) {
      return Error{Errc::malformed, where + ": not a canvas database"};
    }
    return std::move(meta).error();
  }
  {
    const auto& v = meta->format_version;
    auto r = std::from_chars(v.data(), v.data() + v.size(), s.format_version);
    if (r.ec != std::errc() || s.format_version != kStoreFormatVersion) {
      return Error{Errc::unsupported, where + ": format version '" + v.substr(0, 40) + "'"};
    }
  }
  s.canvas = meta->canvas;
  (void)std::from_chars(meta->created_ms.data(), meta->created_ms.data() + meta->created_ms.size(),
                        s.created_ms);
  auto cfg = detail::config_from_meta(*meta, where);
  if (!cfg) return std::move(cfg).error();
  s.config = *cfg;

  const auto query = [&](const char* sql, auto&& row) -> Result<void> {
    auto st = detail::Stmt::prepare(raw, sql, where);
    if (!st) return std::move(st).error();
    for (;;) {
      const int r = st->step();
      if (r == SQLITE_DONE) return {};
      if (r != SQLITE_ROW) return detail::sqlite_error(raw, r, where, sql);
      row(*st);
    }
  };
  auto r = query(
      "SELECT count(*), ifnull(max(seq), 0), ifnull(min(time_ms), 0), ifnull(max(time_ms), 0), "
      "(SELECT count(DISTINCT stroke) FROM events WHERE kind = 3) FROM events",
      [&](detail::Stmt& st) {
        s.events = st.u64(0);
        s.last_seq = st.u64(1);
        s.first_ms = st.i64(2);
        s.last_ms = st.i64(3);
        s.strokes = st.u64(4);
      });
  if (!r) return std::move(r).error();

  std::map<std::uint64_t, AuthorSummary> authors;
  r = query("SELECT artist, ifnull(role, ''), ifnull(name, '') FROM artists",
            [&](detail::Stmt& st) {
              auto& a = authors[st.u64(0)];
              a.artist = st.u64(0);
              a.role = st.text(1);
              a.name = st.text(2);
            });
  if (!r) return std::move(r).error();
  r = query(
      "SELECT artist, count(*), count(DISTINCT CASE WHEN kind = 3 THEN stroke END), "
      "count(CASE WHEN kind IN (4, 5) THEN 1 END), count(CASE WHEN kind = 6 THEN 1 END) "
      "FROM events GROUP BY artist",
      [&](detail::Stmt& st) {
        auto& a = authors[st.u64(0)];
        a.artist = st.u64(0);
        a.events = st.u64(1);
        a.strokes = st.u64(2);
        a.undos = st.u64(3);
        a.imports = st.u64(4);
      });
  if (!r) return std::move(r).error();
  for (auto& [id, a] : authors) s.authors.push_back(std::move(a));

  r = query(
      "SELECT c.id, c.event_seq, c.next_stroke, c.block_count, ifnull(c.created_ms, 0), "
      "length(c.allocator) + ifnull((SELECT sum(length(b.data)) FROM checkpoint_blocks b "
      "WHERE b.checkpoint = c.id), 0), "
      "(SELECT count(*) FROM checkpoint_blocks b WHERE b.checkpoint = c.id) "
      "FROM checkpoints c ORDER BY c.id",
      [&](detail::Stmt& st) {
        CheckpointSummary c;
        c.id = st.u64(0);
        c.event_seq = st.u64(1);
        c.next_stroke = st.u64(2);
        c.block_count = st.u64(3);
        c.created_ms = st.i64(4);
        c.bytes = st.u64(5);
        c.blocks_written = st.u64(6);
        s.checkpoints.push_back(c);
      });
  if (!r) return std::move(r).error();

  std::string integrity;
  r = query("PRAGMA integrity_check", [&](detail::Stmt& st) {
    if (!integrity.empty()) integrity += "\n";
    if (integrity.size() < 64 * 1024) integrity += st.text(0);
  });
  if (!r) integrity = r.error().message;
  s.integrity = integrity;
  s.db_bytes = file_size(db_path);
  s.wal_bytes = file_size(db_path + "-wal");
  return s;
}

std::vector<std::string> list_canvases(const std::string& dir) {
  std::vector<std::string> out;
  std::error_code ec;
  std::filesystem::directory_iterator it(dir, ec), end;
  const std::string suffix = kCanvasFileSuffix;
  for (; !ec && it != end; it.increment(ec)) {
    std::error_code ec2;
    if (!it->is_regular_file(ec2)) continue;
    const std::string f = it->path().filename().string();
    if (f.size() > suffix.size() && f.compare(f.size() - suffix.size(), suffix.size(), suffix) == 0) {
      out.push_back(f.substr(0, f.size() - suffix.size()));
    }
  }
  std::sort(out.begin(), out.end());
  return out;
}

// ---- DataDirLock ----

Result<DataDirLock> DataDirLock::acquire(const std::string& dir) {
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) return Error{Errc::io_error, "cannot create data directory " + dir + ": " + ec.message()};
  const std::string path = (std::filesystem::path(dir) / "lock").string();
  const int fd = ::open(path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
  if (fd < 0) {
    return Error{Errc::io_error, "cannot open " + path + ": " + std::strerror(errno)};
  }
  if (::flock(fd, LOCK_EX | LOCK_NB) != 0) {
    const int err = errno;
    char buf[32] = {};
    const ssize_t n = ::pread(fd, buf, sizeof buf - 1, 0);
    ::close(fd);
    if (err != EWOULDBLOCK) {
      return Error{Errc::io_error, "cannot lock " + path + ": " + std::strerror(err)};
    }
    std::string pid = n > 0 ? std::string(buf, static_cast<std::size_t>(n)) : std::string();
    while (!pid.empty() && (pid.back() == '\n' || pid.back() == ' ')) pid.pop_back();
    if (pid.empty() || !std::all_of(pid.begin(), pid.end(), [](char ch) {
          return ch >= '0' && ch <= '9';
        })) {
      pid = "unknown";
    }
    return Error{Errc::refused,
                 "data directory " + dir + " is in use by another server (pid " + pid + ")"};
  }
  const std::string me = std::to_string(::getpid()) + "\n";
  if (::ftruncate(fd, 0) != 0 ||
      ::pwrite(fd, me.data(), me.size(), 0) != static_cast<ssize_t>(me.size())) {
    const int err = errno;
    ::close(fd);
    return Error{Errc::io_error, "cannot write " + path + ": " + std::strerror(err)};
  }
  DataDirLock lock;
  lock.fd_ = fd;
  lock.dir_ = dir;
  return lock;
}

DataDirLock::DataDirLock(DataDirLock&& other) noexcept
    : fd_(std::exchange(other.fd_, -1)), dir_(std::move(other.dir_)) {}

DataDirLock& DataDirLock::operator=(DataDirLock&& other) noexcept {
  if (this != &other) {
    if (fd_ >= 0) ::close(fd_);
    fd_ = std::exchange(other.fd_, -1);
    dir_ = std::move(other.dir_);
  }
  return *this;
}

DataDirLock::~DataDirLock() {
  if (fd_ >= 0) ::close(fd_);  // closing the descriptor releases the flock
}

}  // namespace deepcanvas::storage
