// Helpers for the storage tests: temporary directories, events, waiting.
#pragma once

#include <gtest/gtest.h>
#include <sqlite3.h>
#include <stdlib.h>

#include <chrono>
#include <filesystem>
#include <functional>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "deepcanvas/server_core/stroke_log.hpp"
#include "deepcanvas/storage/canvas_store.hpp"

namespace deepcanvas::test {

// A fresh directory under /tmp, removed with everything in it at the end of the scope.
class TempDir {
 public:
  TempDir() {
    char tmpl[] = "/tmp/deepcanvas_storage_XXXXXX";
    const char* p = ::mkdtemp(tmpl);
    EXPECT_NE(p, nullptr);
    path_ = p ? p : "/tmp";
  }
  ~TempDir() {
    std::error_code ec;
    if (path_ != "/tmp") std::filesystem::remove_all(path_, ec);
  }
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;
  const std::string& path() const { return path_; }

 private:
  std::string path_;
};

inline server_core::OctreeConfig small_octree() {
  server_core::OctreeConfig c;
  c.edge_m = 8.0;
  c.max_depth = 12;
  c.block_cells = 4096;
  c.max_cells = 1u << 22;
  return c;
}

inline storage::StoreOptions fast_options() {
  storage::StoreOptions o;
  o.sync = false;
  return o;
}

// Stroke `id`'s event `i` (begin, samples or end by i % 3), with recognisable content.
inline server_core::StrokeEvent make_event(std::uint64_t id, int i) {
  server_core::StrokeEvent e;
  e.stroke_id = id;
  e.kind = static_cast<server_core::StrokeEvent::Kind>(1 + i % 3);
  if (e.kind != server_core::StrokeEvent::Kind::end) {
    e.brush.colour[0] = static_cast<float>(id % 7) / 7.0f;
    for (int k = 0; k <= i % 4; ++k) {
      protocol::StrokeSample s;
      s.x = 0.01 * static_cast<double>(id) + k;
      s.y = -0.5 * k;
      s.z = 0.25;
      s.t_ms = static_cast<std::uint32_t>(k * 10 + i);
      e.samples.push_back(s);
    }
  }
  return e;
}

inline bool same_event(const server_core::StrokeEvent& a, const server_core::StrokeEvent& b) {
  auto ea = server_core::encode_stroke_event(a);
  auto eb = server_core::encode_stroke_event(b);
  return ea && eb && *ea == *eb;
}

inline bool wait_until(const std::function<bool()>& pred,
                       std::chrono::milliseconds limit = std::chrono::seconds(20)) {
  const auto end = std::chrono::steady_clock::now() + limit;
  while (!pred()) {
    if (std::chrono::steady_clock::now() > end) return false;
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
  }
  return true;
}

inline std::string canvas_path(const std::string& dir, const std::string& name) {
  return dir + "/" + name + storage::kCanvasFileSuffix;
}

// Runs `sql` on the database file directly (the tests' way of damaging it).
inline void sql_exec(const std::string& path, const std::string& sql) {
  sqlite3* db = nullptr;
  ASSERT_EQ(sqlite3_open(path.c_str(), &db), SQLITE_OK);
  char* err = nullptr;
  const int rc = sqlite3_exec(db, sql.c_str(), nullptr, nullptr, &err);
  EXPECT_EQ(rc, SQLITE_OK) << (err ? err : "");
  sqlite3_free(err);
  sqlite3_close(db);
}

// Flips one byte (at `offset`, from the end when negative) of a blob cell.
inline void flip_blob_byte(const std::string& path, const std::string& table,
                           const std::string& column, const std::string& where_clause,
                           long offset) {
  sqlite3* db = nullptr;
  ASSERT_EQ(sqlite3_open(path.c_str(), &db), SQLITE_OK);
  sqlite3_stmt* st = nullptr;
  const std::string sel = "SELECT " + column + " FROM " + table + " WHERE " + where_clause;
  ASSERT_EQ(sqlite3_prepare_v2(db, sel.c_str(), -1, &st, nullptr), SQLITE_OK);
  ASSERT_EQ(sqlite3_step(st), SQLITE_ROW) << sel;
  const auto* p = static_cast<const std::uint8_t*>(sqlite3_column_blob(st, 0));
  std::vector<std::uint8_t> blob(p, p + sqlite3_column_bytes(st, 0));
  sqlite3_finalize(st);
  ASSERT_FALSE(blob.empty());
  const std::size_t at = offset >= 0 ? static_cast<std::size_t>(offset)
                                     : blob.size() - static_cast<std::size_t>(-offset);
  ASSERT_LT(at, blob.size());
  blob[at] ^= 0x5a;
  const std::string upd = "UPDATE " + table + " SET " + column + " = ? WHERE " + where_clause;
  ASSERT_EQ(sqlite3_prepare_v2(db, upd.c_str(), -1, &st, nullptr), SQLITE_OK);
  sqlite3_bind_blob(st, 1, blob.data(), static_cast<int>(blob.size()), SQLITE_TRANSIENT);
  EXPECT_EQ(sqlite3_step(st), SQLITE_DONE);
  sqlite3_finalize(st);
  sqlite3_close(db);
}

}  // namespace deepcanvas::test
