#include "sqlite_util.hpp"

namespace deepcanvas::storage::detail {

Errc sqlite_errc(int rc) noexcept {
  switch (rc & 0xff) {
    case SQLITE_NOTADB:
    case SQLITE_CORRUPT:
    case SQLITE_FORMAT:
      return Errc::malformed;
    case SQLITE_CANTOPEN:
    case SQLITE_FULL:
    case SQLITE_IOERR:
    case SQLITE_READONLY:
    case SQLITE_BUSY:
    case SQLITE_LOCKED:
    case SQLITE_PERM:
    case SQLITE_PROTOCOL:
      return Errc::io_error;
    case SQLITE_NOMEM:
      return Errc::out_of_memory;
    default:
      return Errc::internal;
  }
}

Error sqlite_error(sqlite3* db, int rc, const std::string& where, std::string_view what) {
  std::string msg = where + ": " + std::string(what) + ": ";
  msg += db ? sqlite3_errmsg(db) : sqlite3_errstr(rc);
  return Error{sqlite_errc(rc), std::move(msg)};
}

Result<Stmt> Stmt::prepare(sqlite3* db, const char* sql, const std::string& where) {
  Stmt s;
  const int rc = sqlite3_prepare_v2(db, sql, -1, &s.s_, nullptr);
  if (rc != SQLITE_OK) return sqlite_error(db, rc, where, "prepare");
  return s;
}

Result<void> exec(sqlite3* db, const char* sql, const std::string& where) {
  char* err = nullptr;
  const int rc = sqlite3_exec(db, sql, nullptr, nullptr, &err);
  if (rc != SQLITE_OK) {
    std::string msg = where + ": " + (err ? err : sqlite3_errstr(rc));
    sqlite3_free(err);
    return Error{sqlite_errc(rc), std::move(msg)};
  }
  return {};
}

Result<MetaValues> read_meta(sqlite3* db, const std::string& where) {
  auto st = Stmt::prepare(db, "SELECT key, value FROM meta", where);
  if (!st) return std::move(st).error();
  MetaValues m;
  for (;;) {
    const int rc = st->step();
    if (rc == SQLITE_DONE) break;
    if (rc != SQLITE_ROW) return sqlite_error(db, rc, where, "reading meta");
    const std::string key = st->text(0);
    std::string value = st->text(1);
    if (value.size() > 4096) value.resize(4096);  // untrusted: keep it bounded
    if (key == "format_version") m.format_version = value;
    else if (key == "canvas") m.canvas = value;
    else if (key == "created_ms") m.created_ms = value;
    else if (key == "roots_per_axis") m.roots_per_axis = value;
    else if (key == "edge_m") m.edge_m = value;
    else if (key == "max_depth") m.max_depth = value;
    else if (key == "block_cells") m.block_cells = value;
    else if (key == "max_cells") m.max_cells = value;
  }
  return m;
}

}  // namespace deepcanvas::storage::detail
