// CanvasStore as a journal: durability across reopen, when_durable, group commit, write failures
// and recovery, corrupt records and salvage, format versions, summaries, the data directory lock.
#include <unistd.h>

#include <atomic>
#include <mutex>

#include "deepcanvas/base/log.hpp"
#include "storage_test_util.hpp"

namespace deepcanvas::test {
namespace {

using storage::CanvasStore;
using storage::StoreOptions;

std::unique_ptr<CanvasStore> open_ok(const std::string& dir, const std::string& name,
                                     const StoreOptions& o = fast_options()) {
  auto s = CanvasStore::open(dir, name, small_octree(), o);
  EXPECT_TRUE(s.ok()) << (s ? "" : s.error().message);
  return s ? std::move(*s) : nullptr;
}

// Appends events 0..n-1 of strokes 1.. (3 events each) and returns them.
std::vector<server_core::StrokeEvent> append_events(CanvasStore& s, int n,
                                                    std::uint64_t first_stroke = 1) {
  std::vector<server_core::StrokeEvent> out;
  for (int i = 0; i < n; ++i) {
    out.push_back(make_event(first_stroke + static_cast<std::uint64_t>(i / 3), i));
    s.append(out.back(), 7);
  }
  return out;
}

class StorageTest : public ::testing::Test {
 protected:
  void SetUp() override { base::set_log_level(base::LogLevel::off); }
  void TearDown() override { base::set_log_level(base::LogLevel::info); }
  TempDir dir;
};

TEST_F(StorageTest, EventsAreDurableAndReadBackInOrder) {
  std::vector<server_core::StrokeEvent> events;
  {
    auto s = open_ok(dir.path(), "c", StoreOptions{});
    ASSERT_TRUE(s);
    EXPECT_TRUE(s->created());
    auto l = s->load();
    ASSERT_TRUE(l.ok()) << l.error().message;
    EXPECT_EQ(l->checkpoint_id, 0u);
    EXPECT_EQ(l->last_seq, 0u);
    EXPECT_TRUE(l->events_after.empty());
    EXPECT_EQ(l->next_stroke_id, 1u);
    s->start();
    events = append_events(*s, 30);
    EXPECT_EQ(s->last_seq(), 30u);
    s->close();
    EXPECT_EQ(s->durable_seq(), 30u);
  }
  auto s = open_ok(dir.path(), "c");
  ASSERT_TRUE(s);
  EXPECT_FALSE(s->created());
  auto l = s->load();
  ASSERT_TRUE(l.ok()) << l.error().message;
  ASSERT_EQ(l->events_after.size(), events.size());
  for (std::size_t i = 0; i < events.size(); ++i) {
    EXPECT_TRUE(same_event(l->events_after[i], events[i])) << "event " << i + 1;
  }
  EXPECT_EQ(l->last_seq, 30u);
  EXPECT_EQ(l->next_stroke_id, 11u);
  ASSERT_TRUE(l->tree);
  // The history continues.
  s->start();
  EXPECT_EQ(s->append(make_event(11, 0), 1), 31u);
  s->close();
  auto again = open_ok(dir.path(), "c");
  auto l2 = again->load();
  ASSERT_TRUE(l2.ok());
  EXPECT_EQ(l2->last_seq, 31u);
  EXPECT_EQ(storage::list_canvases(dir.path()), std::vector<std::string>{"c"});
}

TEST_F(StorageTest, WhenDurableFiresOncePerCallInOrder) {
  auto s = open_ok(dir.path(), "c");
  ASSERT_TRUE(s->load().ok());
  s->start();
  std::mutex m;
  std::vector<std::uint64_t> fired;
  std::atomic<int> errors{0};
  for (int i = 0; i < 200; ++i) {
    const auto seq = s->append(make_event(1 + static_cast<std::uint64_t>(i / 3), i), 1);
    s->when_durable(seq, [&, seq](Result<void> r) {
      if (!r) ++errors;
      std::lock_guard lock(m);
      fired.push_back(seq);
    });
  }
  ASSERT_TRUE(wait_until([&] {
    std::lock_guard lock(m);
    return fired.size() >= 200;
  }));
  // Already durable: at once, on this thread.
  bool now = false;
  s->when_durable(5, [&](Result<void> r) { now = r.ok(); });
  EXPECT_TRUE(now);
  s->close();
  std::lock_guard lock(m);
  ASSERT_EQ(fired.size(), 200u);
  for (std::size_t i = 0; i < fired.size(); ++i) EXPECT_EQ(fired[i], i + 1);
  EXPECT_EQ(errors.load(), 0);
}

TEST_F(StorageTest, GroupCommit) {
  {
    // Queued before the writer starts: one transaction.
    auto s = open_ok(dir.path(), "a", StoreOptions{});
    ASSERT_TRUE(s->load().ok());
    append_events(*s, 1000);
    s->start();
    ASSERT_TRUE(wait_until([&] { return s->durable_seq() == 1000; }));
    EXPECT_EQ(s->commits(), 1u);
    s->close();
  }
  // Appended while the writer runs (synchronous=FULL: every commit syncs).
  auto s = open_ok(dir.path(), "b", StoreOptions{});
  ASSERT_TRUE(s->load().ok());
  s->start();
  constexpr int kEvents = 5000;
  append_events(*s, kEvents);
  ASSERT_TRUE(wait_until([&] { return s->durable_seq() == kEvents; }));
  EXPECT_LT(s->commits(), static_cast<std::uint64_t>(kEvents / 4)) << s->commits();
  s->close();
  auto l = open_ok(dir.path(), "b")->load();
  ASSERT_TRUE(l.ok());
  EXPECT_EQ(l->events_after.size(), static_cast<std::size_t>(kEvents));
}

TEST_F(StorageTest, WriteFailureRefusesThenRecovers) {
  std::atomic<bool> full{false};
  std::atomic<int> attempts{0};
  StoreOptions o = fast_options();
  o.before_write = [&]() -> Result<void> {
    ++attempts;
    if (full) return Error{Errc::io_error, "disk full (injected)"};
    return {};
  };
  auto s = open_ok(dir.path(), "c", o);
  ASSERT_TRUE(s->load().ok());
  s->start();
  auto first = append_events(*s, 3);
  ASSERT_TRUE(wait_until([&] { return s->durable_seq() == 3; }));
  EXPECT_TRUE(s->accepting().ok());

  full = true;
  std::atomic<int> ok{0}, failed{0};
  std::vector<server_core::StrokeEvent> more;
  for (int i = 0; i < 12; ++i) {
    more.push_back(make_event(2 + static_cast<std::uint64_t>(i / 3), i));
    const auto seq = s->append(more.back(), 2);
    s->when_durable(seq, [&](Result<void> r) { ++(r ? ok : failed); });
  }
  ASSERT_TRUE(wait_until([&] { return !s->accepting().ok(); }));
  const auto err = s->accepting();
  ASSERT_FALSE(err.ok());
  EXPECT_EQ(err.error().code, Errc::io_error);
  EXPECT_NE(err.error().message.find("canvas 'c' cannot store strokes"), std::string::npos)
      << err.error().message;
  EXPECT_NE(err.error().message.find("disk full (injected)"), std::string::npos);
  const int before = attempts.load();
  ASSERT_TRUE(wait_until([&] { return attempts.load() >= before + 2; }));  // retried
  EXPECT_EQ(ok.load(), 0);
  EXPECT_EQ(failed.load(), 0);
  EXPECT_EQ(s->durable_seq(), 3u);

  full = false;
  ASSERT_TRUE(wait_until([&] { return ok.load() == 12; }));
  EXPECT_TRUE(s->accepting().ok());
  EXPECT_EQ(s->durable_seq(), 15u);
  s->close();
  auto l = open_ok(dir.path(), "c")->load();
  ASSERT_TRUE(l.ok());
  ASSERT_EQ(l->events_after.size(), 15u);
  for (std::size_t i = 0; i < more.size(); ++i) {
    EXPECT_TRUE(same_event(l->events_after[3 + i], more[i]));
  }
}

TEST_F(StorageTest, CloseWhileFailingReportsErrors) {
  StoreOptions o = fast_options();
  o.before_write = []() -> Result<void> { return Error{Errc::io_error, "disk full (injected)"}; };
  auto s = open_ok(dir.path(), "c", o);
  ASSERT_TRUE(s->load().ok());
  s->start();
  std::atomic<int> failed{0};
  const auto seq = s->append(make_event(1, 0), 1);
  s->when_durable(seq, [&](Result<void> r) { failed += r.ok() ? 0 : 1; });
  s->close();
  EXPECT_EQ(failed.load(), 1);
}

TEST_F(StorageTest, CorruptEventFailsLoadAndSalvageKeepsTheEventsBefore) {
  {
    auto s = open_ok(dir.path(), "c");
    ASSERT_TRUE(s->load().ok());
    s->start();
    append_events(*s, 20);
    s->close();
  }
  const std::string path = canvas_path(dir.path(), "c");
  flip_blob_byte(path, "events", "record", "seq = 12", -2);
  {
    auto s = open_ok(dir.path(), "c");
    auto l = s->load();
    ASSERT_FALSE(l.ok());
    EXPECT_EQ(l.error().code, Errc::malformed);
    const auto& msg = l.error().message;
    EXPECT_NE(msg.find("canvas 'c'"), std::string::npos) << msg;
    EXPECT_NE(msg.find(path), std::string::npos) << msg;
    EXPECT_NE(msg.find("event 12"), std::string::npos) << msg;
    EXPECT_NE(msg.find("--salvage"), std::string::npos) << msg;
    EXPECT_NE(msg.find("11 events"), std::string::npos) << msg;
  }
  {
    auto s = open_ok(dir.path(), "c");
    auto l = s->load(true);
    ASSERT_TRUE(l.ok()) << l.error().message;
    EXPECT_EQ(l->events_after.size(), 11u);
    EXPECT_EQ(l->last_seq, 11u);
    ASSERT_FALSE(l->notes.empty());
    EXPECT_NE(l->notes.back().find("dropped 9"), std::string::npos) << l->notes.back();
    s->start();
    EXPECT_EQ(s->append(make_event(99, 0), 1), 12u);
    s->close();
  }
  auto l = open_ok(dir.path(), "c")->load();
  ASSERT_TRUE(l.ok()) << l.error().message;
  EXPECT_EQ(l->events_after.size(), 12u);
  EXPECT_EQ(l->events_after.back().stroke_id, 99u);
}

TEST_F(StorageTest, MismatchedColumnsAndGapsAreMalformed) {
  {
    auto s = open_ok(dir.path(), "c");
    ASSERT_TRUE(s->load().ok());
    append_events(*s, 10);
    s->close();  // never started: close writes the queue itself
  }
  const std::string path = canvas_path(dir.path(), "c");
  sql_exec(path, "DELETE FROM events WHERE seq = 4");
  auto l = open_ok(dir.path(), "c")->load();
  ASSERT_FALSE(l.ok());
  EXPECT_NE(l.error().message.find("event 4: missing"), std::string::npos) << l.error().message;
}

TEST_F(StorageTest, UnknownFormatVersionIsUnsupported) {
  { auto s = open_ok(dir.path(), "c"); }
  const std::string path = canvas_path(dir.path(), "c");
  sql_exec(path, "UPDATE meta SET value = '999' WHERE key = 'format_version'");
  auto s = CanvasStore::open(dir.path(), "c", small_octree(), fast_options());
  ASSERT_FALSE(s.ok());
  EXPECT_EQ(s.error().code, Errc::unsupported);
  EXPECT_NE(s.error().message.find(path), std::string::npos) << s.error().message;
  auto sum = storage::summarize(path);
  ASSERT_FALSE(sum.ok());
  EXPECT_EQ(sum.error().code, Errc::unsupported);
}

TEST_F(StorageTest, NotADatabaseAndBadNames) {
  const std::string path = canvas_path(dir.path(), "junk");
  {
    FILE* f = std::fopen(path.c_str(), "wb");
    ASSERT_NE(f, nullptr);
    std::fputs("this is not a database at all, just some bytes to fill a page", f);
    std::fclose(f);
  }
  auto s = CanvasStore::open(dir.path(), "junk", small_octree(), fast_options());
  ASSERT_FALSE(s.ok());
  EXPECT_EQ(s.error().code, Errc::malformed) << s.error().message;
  for (const char* bad : {"", "..", "a/b"}) {
    auto b = CanvasStore::open(dir.path(), bad, small_octree(), fast_options());
    ASSERT_FALSE(b.ok());
    EXPECT_EQ(b.error().code, Errc::invalid_argument);
  }
}

TEST_F(StorageTest, StoredConfigWins) {
  { auto s = open_ok(dir.path(), "c"); }
  server_core::OctreeConfig other = small_octree();
  other.edge_m = 123.5;
  auto s = CanvasStore::open(dir.path(), "c", other, fast_options());
  ASSERT_TRUE(s.ok());
  EXPECT_EQ((*s)->config().edge_m, small_octree().edge_m);
  EXPECT_EQ((*s)->config().max_cells, small_octree().max_cells);
}

TEST_F(StorageTest, SummaryCountsAuthorsAndStrokes) {
  {
    auto s = open_ok(dir.path(), "c");
    ASSERT_TRUE(s->load().ok());
    s->start();
    s->note_artist({7, "painter", "Ada"});
    s->note_artist({8, "admin", ""});
    append_events(*s, 9);  // strokes 1..3 by artist 7, all ended
    s->append(make_event(4, 0), 8);
    s->append(make_event(4, 2), 8);
    s->note_artist({7, "painter", "Ada L."});
    s->close();
  }
  auto sum = storage::summarize(canvas_path(dir.path(), "c"));
  ASSERT_TRUE(sum.ok()) << sum.error().message;
  EXPECT_EQ(sum->canvas, "c");
  EXPECT_EQ(sum->events, 11u);
  EXPECT_EQ(sum->last_seq, 11u);
  EXPECT_EQ(sum->strokes, 4u);
  ASSERT_EQ(sum->authors.size(), 2u);
  EXPECT_EQ(sum->authors[0].artist, 7u);
  EXPECT_EQ(sum->authors[0].name, "Ada L.");
  EXPECT_EQ(sum->authors[0].strokes, 3u);
  EXPECT_EQ(sum->authors[1].role, "admin");
  EXPECT_EQ(sum->authors[1].strokes, 1u);
  EXPECT_EQ(sum->integrity, "ok");
  EXPECT_GT(sum->db_bytes + sum->wal_bytes, 0u);
  EXPECT_GT(sum->last_ms, 0);
  EXPECT_EQ(sum->config.edge_m, small_octree().edge_m);
  EXPECT_TRUE(sum->checkpoints.empty());
}

TEST_F(StorageTest, WantsCheckpointByEventsAndTime) {
  StoreOptions o = fast_options();
  o.checkpoint_every_events = 5;
  o.checkpoint_every = std::chrono::hours(1);
  auto s = open_ok(dir.path(), "c", o);
  ASSERT_TRUE(s->load().ok());
  s->start();
  EXPECT_FALSE(s->wants_checkpoint());  // nothing since
  append_events(*s, 4);
  EXPECT_FALSE(s->wants_checkpoint());
  s->append(make_event(9, 2), 1);
  EXPECT_TRUE(s->wants_checkpoint());
  s->close();

  o.checkpoint_every_events = 1000;
  o.checkpoint_every = std::chrono::milliseconds(20);
  auto t = open_ok(dir.path(), "d", o);
  ASSERT_TRUE(t->load().ok());
  t->start();
  t->append(make_event(1, 0), 1);
  EXPECT_TRUE(wait_until([&] { return t->wants_checkpoint(); }));
  t->close();
}

TEST_F(StorageTest, DataDirLockIsExclusive) {
  const std::string d = dir.path() + "/data";
  auto a = storage::DataDirLock::acquire(d);
  ASSERT_TRUE(a.ok()) << a.error().message;
  EXPECT_TRUE(a->held());
  auto b = storage::DataDirLock::acquire(d);
  ASSERT_FALSE(b.ok());
  EXPECT_EQ(b.error().code, Errc::refused);
  EXPECT_NE(b.error().message.find("pid " + std::to_string(::getpid())), std::string::npos)
      << b.error().message;
  EXPECT_NE(b.error().message.find(d), std::string::npos);
  storage::DataDirLock moved = std::move(*a);
  EXPECT_TRUE(moved.held());
  moved = storage::DataDirLock();
  auto c = storage::DataDirLock::acquire(d);
  EXPECT_TRUE(c.ok());
}

}  // namespace
}  // namespace deepcanvas::test
