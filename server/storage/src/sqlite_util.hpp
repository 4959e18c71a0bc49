// Thin RAII wrappers over the SQLite C API for the store (internal).
#pragma once

#include <sqlite3.h>

#include <cstdint>
#include <span>
#include <string>
#include <string_view>
#include <utility>

#include "deepcanvas/base/result.hpp"

namespace deepcanvas::storage::detail {

// io_error for full disks and I/O failures, malformed for "not a database"/corruption.
Errc sqlite_errc(int rc) noexcept;
Error sqlite_error(sqlite3* db, int rc, const std::string& where, std::string_view what);

class Db {
 public:
  Db() = default;
  explicit Db(sqlite3* h) : h_(h) {}
  Db(Db&& o) noexcept : h_(std::exchange(o.h_, nullptr)) {}
  Db& operator=(Db&& o) noexcept {
    if (this != &o) {
      reset();
      h_ = std::exchange(o.h_, nullptr);
    }
    return *this;
  }
  Db(const Db&) = delete;
  Db& operator=(const Db&) = delete;
  ~Db() { reset(); }
  void reset() noexcept {
    if (h_) sqlite3_close_v2(h_);
    h_ = nullptr;
  }
  sqlite3* get() const noexcept { return h_; }

 private:
  sqlite3* h_ = nullptr;
};

class Stmt {
 public:
  Stmt() = default;
  Stmt(Stmt&& o) noexcept : s_(std::exchange(o.s_, nullptr)) {}
  Stmt& operator=(Stmt&& o) noexcept {
    if (this != &o) {
      finalize();
      s_ = std::exchange(o.s_, nullptr);
    }
    return *this;
  }
  Stmt(const Stmt&) = delete;
  Stmt& operator=(const Stmt&) = delete;
  ~Stmt() { finalize(); }
  void finalize() noexcept {
    if (s_) sqlite3_finalize(s_);
    s_ = nullptr;
  }

  static Result<Stmt> prepare(sqlite3* db, const char* sql, const std::string& where);

  void reset() noexcept {
    sqlite3_reset(s_);
    sqlite3_clear_bindings(s_);
  }
  void bind(int i, std::int64_t v) noexcept { sqlite3_bind_int64(s_, i, v); }
  void bind_u64(int i, std::uint64_t v) noexcept {
    sqlite3_bind_int64(s_, i, static_cast<std::int64_t>(v));
  }
  void bind_text(int i, std::string_view v) noexcept {
    sqlite3_bind_text(s_, i, v.data(), static_cast<int>(v.size()), SQLITE_TRANSIENT);
  }
  // The bytes must stay valid until the statement is stepped and reset.
  void bind_blob(int i, std::span<const std::uint8_t> v) noexcept {
    sqlite3_bind_blob(s_, i, v.empty() ? "" : static_cast<const void*>(v.data()),
                      static_cast<int>(v.size()), SQLITE_STATIC);
  }
  int step() noexcept { return sqlite3_step(s_); }

  std::int64_t i64(int col) const noexcept { return sqlite3_column_int64(s_, col); }
  std::uint64_t u64(int col) const noexcept {
    return static_cast<std::uint64_t>(sqlite3_column_int64(s_, col));
  }
  int type(int col) const noexcept { return sqlite3_column_type(s_, col); }
  std::string text(int col) const {
    const auto* p = sqlite3_column_text(s_, col);
    const int n = sqlite3_column_bytes(s_, col);
    return p ? std::string(reinterpret_cast<const char*>(p), static_cast<std::size_t>(n))
             : std::string();
  }
  std::span<const std::uint8_t> blob(int col) const noexcept {
    const void* p = sqlite3_column_blob(s_, col);
    const int n = sqlite3_column_bytes(s_, col);
    if (!p || n <= 0) return {};
    return {static_cast<const std::uint8_t*>(p), static_cast<std::size_t>(n)};
  }
  sqlite3_stmt* get() const noexcept { return s_; }

 private:
  sqlite3_stmt* s_ = nullptr;
};

Result<void> exec(sqlite3* db, const char* sql, const std::string& where);

// Reads the meta table: missing keys are empty strings.
struct MetaValues {
  std::string format_version, canvas, created_ms;
  std::string roots_per_axis, edge_m, max_depth, block_cells, max_cells;
};
Result<MetaValues> read_meta(sqlite3* db, const std::string& where);

}  // namespace deepcanvas::storage::detail
