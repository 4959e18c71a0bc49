// The stroke log (stroke_log.hpp): the version-2 layout pinned byte for byte, round trips of
// every event kind, recovery of every truncated prefix, corruption detection, version-1 files,
// records refused with a reason, the writer's append/recovery and the recorder's failure path.
#include <gtest/gtest.h>
#include <spdlog/sinks/ostream_sink.h>
#include <unistd.h>

#include <bit>
#include <filesystem>
#include <fstream>
#include <map>
#include <random>
#include <sstream>

#include "deepcanvas/base/log.hpp"
#include "deepcanvas/paintings/apa.hpp"
#include "deepcanvas/server_core/stroke_log.hpp"

namespace deepcanvas {
namespace {

using server_core::kStrokeLogHeaderBytes;
using server_core::read_stroke_log;
using server_core::StrokeEvent;
using Kind = StrokeEvent::Kind;

// Little-endian writers, spelled out here so that the test states the layout independently of
// the implementation.
struct Bytes {
  std::vector<std::uint8_t> b;
  Bytes& u8(std::uint8_t v) {
    b.push_back(v);
    return *this;
  }
  Bytes& u32(std::uint32_t v) {
    for (int i = 0; i < 4; ++i) b.push_back(static_cast<std::uint8_t>(v >> (8 * i)));
    return *this;
  }
  Bytes& u64(std::uint64_t v) {
    for (int i = 0; i < 8; ++i) b.push_back(static_cast<std::uint8_t>(v >> (8 * i)));
    return *this;
  }
  Bytes& f32(float v) { return u32(std::bit_cast<std::uint32_t>(v)); }
  Bytes& f64(double v) { return u64(std::bit_cast<std::uint64_t>(v)); }
  Bytes& brush(const protocol::Brush& br) {
    u8(static_cast<std::uint8_t>(br.mode));
    for (float c : br.colour) f32(c);
    return f32(br.opacity).f32(br.hardness);
  }
  Bytes& samples(const std::vector<protocol::StrokeSample>& s) {
    u32(static_cast<std::uint32_t>(s.size()));
    for (const auto& p : s) f64(p.x).f64(p.y).f64(p.z).f32(p.radius).f32(p.pressure).u32(p.t_ms);
    return *this;
  }
};

// A record around `payload`: length, FNV-1a-64 of (length bytes + payload), payload.
std::vector<std::uint8_t> record(const std::vector<std::uint8_t>& payload) {
  Bytes len;
  len.u32(static_cast<std::uint32_t>(payload.size()));
  std::uint64_t h = server_core::fnv1a64(len.b);
  h = server_core::fnv1a64(payload, h);
  Bytes r = len;
  r.u64(h);
  r.b.insert(r.b.end(), payload.begin(), payload.end());
  return r.b;
}

std::vector<std::uint8_t> header(std::uint32_t version) {
  Bytes h;
  for (char c : std::string("DCSTROKE")) h.u8(static_cast<std::uint8_t>(c));
  return h.u32(version).u32(0).b;
}

// A version-1 record, as version-1 writers wrote them: one whole stroke.
std::vector<std::uint8_t> v1_record(const protocol::Stroke& s) {
  Bytes p;
  p.u64(s.id).brush(s.brush).samples(s.samples);
  return record(p.b);
}

protocol::StrokeSample random_sample(std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-1, 1);
  protocol::StrokeSample p;
  p.x = u(rng) * 1e3, p.y = u(rng), p.z = u(rng) * 1e-3;
  p.radius = static_cast<float>(0.01 + 0.01 * u(rng));
  p.pressure = 0.5f;
  p.t_ms = rng();
  return p;
}

std::vector<protocol::Stroke> random_strokes(int n, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1, 1);
  std::vector<protocol::Stroke> out;
  for (int i = 0; i < n; ++i) {
    protocol::Stroke s;
    s.id = rng();
    s.brush.mode = static_cast<protocol::BrushMode>(rng() % protocol::kBrushModeCount);
    for (float& c : s.brush.colour) c = static_cast<float>(0.5 + 0.5 * u(rng));
    s.brush.opacity = 0.75f;
    s.brush.hardness = 0.25f;
    const int m = static_cast<int>(rng() % 5);
    for (int k = 0; k < m; ++k) s.samples.push_back(random_sample(rng));
    out.push_back(s);
  }
  return out;
}

// Several strokes' events interleaved at random, as a server with several artists records them:
// each stroke begins, gets 0..3 sample batches, and (mostly) ends.
std::vector<StrokeEvent> random_events(int strokes, unsigned seed) {
  std::mt19937 rng(seed);
  const auto whole = random_strokes(strokes, seed + 1000);
  std::vector<std::vector<StrokeEvent>> per;
  for (const auto& s : whole) {
    std::vector<StrokeEvent> ev;
    ev.push_back(StrokeEvent{Kind::begin, s.id, s.brush, s.samples});
    for (unsigned k = rng() % 4; k > 0; --k) {
      StrokeEvent e{Kind::samples, s.id, {}, {}};
      for (unsigned j = rng() % 4; j > 0; --j) e.samples.push_back(random_sample(rng));
      ev.push_back(e);
    }
    if (rng() % 5 != 0) ev.push_back(StrokeEvent{Kind::end, s.id, {}, {}});
    per.push_back(std::move(ev));
  }
  std::vector<StrokeEvent> out;
  std::vector<std::size_t> next(per.size(), 0);
  for (std::size_t left = per.size(); left > 0;) {
    const std::size_t i = rng() % per.size();
    if (next[i] == per[i].size()) continue;
    out.push_back(per[i][next[i]++]);
    if (next[i] == per[i].size()) --left;
  }
  return out;
}

std::vector<std::uint8_t> encode(const std::vector<StrokeEvent>& events) {
  auto b = server_core::stroke_log_header();
  for (const auto& e : events) {
    const auto r = server_core::encode_stroke_event(e);
    EXPECT_TRUE(r) << r.error().message;
    if (r) b.insert(b.end(), r->begin(), r->end());
  }
  return b;
}

void expect_same_samples(const std::vector<protocol::StrokeSample>& a,
                         const std::vector<protocol::StrokeSample>& b) {
  ASSERT_EQ(a.size(), b.size());
  for (std::size_t i = 0; i < a.size(); ++i) {
    EXPECT_EQ(a[i].x, b[i].x);
    EXPECT_EQ(a[i].y, b[i].y);
    EXPECT_EQ(a[i].z, b[i].z);
    EXPECT_EQ(a[i].radius, b[i].radius);
    EXPECT_EQ(a[i].pressure, b[i].pressure);
    EXPECT_EQ(a[i].t_ms, b[i].t_ms);
  }
}

void expect_same_brush(const protocol::Brush& a, const protocol::Brush& b) {
  EXPECT_EQ(a.mode, b.mode);
  for (int i = 0; i < 4; ++i) EXPECT_EQ(a.colour[i], b.colour[i]);
  EXPECT_EQ(a.opacity, b.opacity);
  EXPECT_EQ(a.hardness, b.hardness);
}

void expect_same(const StrokeEvent& a, const StrokeEvent& b) {
  EXPECT_EQ(a.kind, b.kind);
  EXPECT_EQ(a.stroke_id, b.stroke_id);
  if (a.kind == Kind::begin) expect_same_brush(a.brush, b.brush);
  expect_same_samples(a.samples, b.samples);
}

void expect_same(const protocol::Stroke& a, const protocol::Stroke& b) {
  EXPECT_EQ(a.id, b.id);
  expect_same_brush(a.brush, b.brush);
  expect_same_samples(a.samples, b.samples);
}

TEST(StrokeLog, LayoutIsPinnedByteForByte) {
  EXPECT_EQ(server_core::stroke_log_header(), header(2));
  EXPECT_EQ(server_core::kStrokeLogVersion, 2u);

  // An end event: the whole record, checksum included (FNV-1a-64 computed by hand once).
  const auto end = server_core::encode_stroke_event({Kind::end, 0x0102030405060708ull, {}, {}});
  ASSERT_TRUE(end);
  const std::vector<std::uint8_t> expected_end = {
      0x09, 0x00, 0x00, 0x00,                           // L = 9
      0xbd, 0x9a, 0xfd, 0x41, 0xe4, 0x6c, 0x67, 0x9a,   // FNV-1a-64 0x9a676ce441fd9abd
      0x03,                                             // kind end
      0x08, 0x07, 0x06, 0x05, 0x04, 0x03, 0x02, 0x01};  // stroke id
  EXPECT_EQ(*end, expected_end);

  protocol::StrokeSample smp;
  smp.x = 1.5, smp.y = -2.25, smp.z = 1e-3;
  smp.radius = 0.125f, smp.pressure = 0.75f, smp.t_ms = 0xA0B0C0D0u;
  protocol::Brush br;
  br.mode = protocol::BrushMode::erase;
  br.colour[0] = 0.1f, br.colour[1] = 0.2f, br.colour[2] = 0.3f, br.colour[3] = 1.0f;
  br.opacity = 0.5f, br.hardness = 0.25f;

  const auto begin = server_core::encode_stroke_event({Kind::begin, 7, br, {smp, smp}});
  ASSERT_TRUE(begin);
  Bytes bp;
  bp.u8(1).u64(7).brush(br).samples({smp, smp});
  ASSERT_EQ(bp.b.size(), 38u + 36u * 2);
  EXPECT_EQ(*begin, record(bp.b));

  const auto samples = server_core::encode_stroke_event({Kind::samples, 7, br, {smp}});
  ASSERT_TRUE(samples);
  Bytes sp;
  sp.u8(2).u64(7).samples({smp});  // the brush of a samples event is not written
  ASSERT_EQ(sp.b.size(), 13u + 36u);
  EXPECT_EQ(*samples, record(sp.b));

  // Samples of an end event are not written either.
  // A paste (an import): kind 6, the id, then the encoded cells as they are.
  server_core::StrokeEvent paste{Kind::paste, 9, {}, {}};
  paste.paste = {0xAA, 0xBB, 0xCC};
  const auto pasted = server_core::encode_stroke_event(paste);
  ASSERT_TRUE(pasted);
  EXPECT_EQ(std::vector<std::uint8_t>(pasted->begin() + 12, pasted->end()),
            (std::vector<std::uint8_t>{6, 9, 0, 0, 0, 0, 0, 0, 0, 0xAA, 0xBB, 0xCC}));
  {
    auto log = server_core::stroke_log_header();
    log.insert(log.end(), pasted->begin(), pasted->end());
    auto back = read_stroke_log(log);
    ASSERT_TRUE(back);
    ASSERT_EQ(back->events.size(), 1u);
    EXPECT_EQ(back->events[0].kind, Kind::paste);
    EXPECT_EQ(back->events[0].paste, paste.paste);
  }
  EXPECT_EQ(*server_core::encode_stroke_event({Kind::end, 0x0102030405060708ull, br, {smp}}),
            expected_end);
}

TEST(StrokeLog, EveryKindRoundTrips) {
  const auto events = random_events(20, 1);
  const auto bytes = encode(events);
  auto r = read_stroke_log(bytes);
  ASSERT_TRUE(r) << r.error().message;
  EXPECT_EQ(r->version, 2u);
  EXPECT_FALSE(r->tail);
  EXPECT_EQ(r->valid_bytes, bytes.size());
  ASSERT_EQ(r->events.size(), events.size());
  int kinds[4] = {0, 0, 0, 0};
  for (std::size_t i = 0; i < events.size(); ++i) {
    expect_same(events[i], r->events[i]);
    ++kinds[static_cast<int>(events[i].kind)];
  }
  EXPECT_GT(kinds[1], 0);
  EXPECT_GT(kinds[2], 0);
  EXPECT_GT(kinds[3], 0);
}

TEST(StrokeLog, EveryTruncatedPrefixRecoversTheRecordsBeforeIt) {
  const auto events = random_events(4, 2);
  const auto bytes = encode(events);
  std::vector<std::size_t> ends{kStrokeLogHeaderBytes};
  for (const auto& e : events)
    ends.push_back(ends.back() + server_core::encode_stroke_event(e)->size());
  ASSERT_EQ(ends.back(), bytes.size());
  for (std::size_t n = 0; n < bytes.size(); ++n) {
    auto r = read_stroke_log(std::span(bytes.data(), n));
    if (n < kStrokeLogHeaderBytes) {
      ASSERT_FALSE(r) << n;
      EXPECT_EQ(r.error().code, Errc::malformed);
      continue;
    }
    ASSERT_TRUE(r) << n;
    // Complete records before n are all recovered; a partial record is reported as the tail.
    std::size_t complete = 0;
    while (complete + 1 < ends.size() && ends[complete + 1] <= n) ++complete;
    ASSERT_EQ(r->events.size(), complete) << n;
    for (std::size_t i = 0; i < complete; ++i) expect_same(events[i], r->events[i]);
    EXPECT_EQ(r->valid_bytes, ends[complete]) << n;
    if (n == ends[complete]) {
      EXPECT_FALSE(r->tail) << n;
    } else {
      ASSERT_TRUE(r->tail) << n;
      EXPECT_EQ(r->tail->offset, ends[complete]);
      EXPECT_NE(r->tail->reason.find("torn"), std::string::npos) << r->tail->reason;
    }
  }
}

TEST(StrokeLog, EveryCorruptedByteIsDetected) {
  const auto events = random_events(2, 3);
  const auto bytes = encode(events);
  const std::size_t first_end =
      kStrokeLogHeaderBytes + server_core::encode_stroke_event(events[0])->size();
  for (std::size_t i = 0; i < bytes.size(); ++i) {
    for (std::uint8_t flip : {std::uint8_t{0x01}, std::uint8_t{0x80}}) {
      auto b = bytes;
      b[i] ^= flip;
      auto r = read_stroke_log(b);
      if (i < 12) {  // magic or version
        EXPECT_FALSE(r) << i;
        continue;
      }
      if (i < kStrokeLogHeaderBytes) continue;  // reserved header word
      ASSERT_TRUE(r) << i;
      ASSERT_TRUE(r->tail) << "corruption at byte " << i << " went unnoticed";
      EXPECT_LT(r->events.size(), events.size());
      if (i >= first_end) {
        EXPECT_GE(r->events.size(), 1u);
      }
    }
  }
}

TEST(StrokeLog, CorruptChecksumStopsTheRead) {
  const auto events = random_events(3, 4);
  auto bytes = encode(events);
  const std::size_t second =
      kStrokeLogHeaderBytes + server_core::encode_stroke_event(events[0])->size();
  bytes[second + 4] ^= 0xff;  // the second record's checksum
  auto r = read_stroke_log(bytes);
  ASSERT_TRUE(r);
  ASSERT_EQ(r->events.size(), 1u);
  ASSERT_TRUE(r->tail);
  EXPECT_EQ(r->tail->offset, second);
  EXPECT_EQ(r->tail->reason, "corrupt record: checksum mismatch");
  EXPECT_EQ(r->valid_bytes, second);
}

TEST(StrokeLog, VersionOneFilesStillRead) {
  const auto strokes = random_strokes(6, 5);
  auto bytes = header(1);
  for (const auto& s : strokes) {
    const auto rec = v1_record(s);
    bytes.insert(bytes.end(), rec.begin(), rec.end());
  }
  auto r = read_stroke_log(bytes);
  ASSERT_TRUE(r) << r.error().message;
  EXPECT_EQ(r->version, 1u);
  EXPECT_FALSE(r->tail);
  ASSERT_EQ(r->events.size(), 2 * strokes.size());
  for (std::size_t i = 0; i < strokes.size(); ++i) {
    const auto want = server_core::stroke_events(strokes[i]);
    expect_same(want[0], r->events[2 * i]);
    expect_same(want[1], r->events[2 * i + 1]);
  }
  const auto whole = server_core::assemble_strokes(r->events);
  ASSERT_EQ(whole.size(), strokes.size());
  for (std::size_t i = 0; i < strokes.size(); ++i) expect_same(strokes[i], whole[i]);

  // A torn version-1 record is reported like a version-2 one.
  bytes.resize(bytes.size() - 3);
  auto torn = read_stroke_log(bytes);
  ASSERT_TRUE(torn);
  EXPECT_EQ(torn->events.size(), 2 * (strokes.size() - 1));
  ASSERT_TRUE(torn->tail);
  EXPECT_NE(torn->tail->reason.find("torn"), std::string::npos);
}

TEST(StrokeLog, UnknownVersionIsRefused) {
  auto r = read_stroke_log(header(3));
  ASSERT_FALSE(r);
  EXPECT_EQ(r.error().code, Errc::unsupported);
  EXPECT_NE(r.error().message.find("version 3"), std::string::npos);
}

// Records whose checksum matches but whose content cannot be an event: each is refused with a
// reason naming what is wrong, and the events before it are kept.
TEST(StrokeLog, BadKindsAndLengthsAreRefusedWithAReason) {
  const protocol::Stroke good = random_strokes(1, 6)[0];
  protocol::StrokeSample smp;
  struct Case {
    std::vector<std::uint8_t> payload;
    std::string reason;
  };
  std::vector<Case> cases;
  cases.push_back({Bytes{}.u8(0).u64(1).b, "corrupt record: unknown event kind 0"});
  cases.push_back({Bytes{}.u8(7).u64(1).b, "corrupt record: unknown event kind 7"});
  cases.push_back({Bytes{}.u8(6).u64(1).b, "corrupt record: a paste event with no cells"});
  cases.push_back({Bytes{}.u8(4).u64(1).u8(0).b,
                   "corrupt record: payload of 10 bytes for event kind 4 (exactly 9)"});
  cases.push_back(
      {Bytes{}.u8(3).u64(1).u8(0).b,
       "corrupt record: payload of 10 bytes for event kind 3 (exactly 9)"});
  cases.push_back({Bytes{}.u8(1).u64(1).brush(good.brush).b,
                   "corrupt record: begin payload of 34 bytes (at least 38)"});
  cases.push_back(
      {Bytes{}.u8(2).u64(1).u8(0).b, "corrupt record: samples payload of 10 bytes (at least 13)"});
  cases.push_back({Bytes{}.u8(2).u64(1).u32(2).f64(0).f64(0).f64(0).f32(0).f32(0).u32(0).b,
                   "corrupt record: sample count 2 does not match the payload length"});
  cases.push_back({Bytes{}.u8(2).u64(1).samples({smp}).u8(0).b,
                   "corrupt record: sample count 1 does not match the payload length"});
  Bytes bad_mode;
  bad_mode.u8(1).u64(1).u8(protocol::kBrushModeCount).b.resize(38 - 4, 0);
  bad_mode.u32(0);
  cases.push_back({bad_mode.b, "corrupt record: unknown brush mode " +
                                   std::to_string(protocol::kBrushModeCount)});
  cases.push_back({Bytes{}.u8(3).u32(1).b, "corrupt record: impossible payload length 5"});

  const auto first = server_core::encode_stroke_event(server_core::stroke_events(good)[0]);
  ASSERT_TRUE(first);
  for (const auto& c : cases) {
    auto bytes = server_core::stroke_log_header();
    bytes.insert(bytes.end(), first->begin(), first->end());
    const auto rec = record(c.payload);
    bytes.insert(bytes.end(), rec.begin(), rec.end());
    auto r = read_stroke_log(bytes);
    ASSERT_TRUE(r) << c.reason;
    ASSERT_EQ(r->events.size(), 1u) << c.reason;
    ASSERT_TRUE(r->tail) << c.reason;
    EXPECT_EQ(r->tail->offset, kStrokeLogHeaderBytes + first->size());
    EXPECT_EQ(r->tail->reason, c.reason);
  }

  // A length past kMaxRecordBytes is refused from the length alone (nothing that large is read).
  auto bytes = server_core::stroke_log_header();
  Bytes huge;
  huge.u32(static_cast<std::uint32_t>(server_core::kMaxRecordBytes + 1)).u64(0);
  bytes.insert(bytes.end(), huge.b.begin(), huge.b.end());
  auto r = read_stroke_log(bytes);
  ASSERT_TRUE(r);
  ASSERT_TRUE(r->tail);
  EXPECT_EQ(r->tail->reason, "corrupt record: impossible payload length " +
                                 std::to_string(server_core::kMaxRecordBytes + 1));

  // The encoder refuses an event too large for a record instead of writing a bad length.
  StrokeEvent big{Kind::samples, 1, {}, {}};
  big.samples.resize(server_core::kMaxRecordBytes / 36);
  auto enc = server_core::encode_stroke_event(big);
  ASSERT_FALSE(enc);
  EXPECT_EQ(enc.error().code, Errc::limit_exceeded);
}

// Property: assembling strokes from any interleaving gives each stroke's brush and samples in
// order, strokes in the order of their begins (a brute-force reference built per stroke id).
TEST(StrokeLog, AssembleStrokesMatchesAReference) {
  for (unsigned seed = 0; seed < 20; ++seed) {
    const auto events = random_events(8, 100 + seed);
    std::vector<std::uint64_t> order;
    std::map<std::uint64_t, protocol::Stroke> want;
    for (const auto& e : events) {
      if (e.kind == Kind::begin) {
        order.push_back(e.stroke_id);
        want[e.stroke_id] = protocol::Stroke{e.stroke_id, e.brush, e.samples};
      } else if (e.kind == Kind::samples) {
        auto& s = want[e.stroke_id].samples;
        s.insert(s.end(), e.samples.begin(), e.samples.end());
      }
    }
    // Events of a stroke that never began are skipped.
    auto with_stray = events;
    with_stray.insert(with_stray.begin(), StrokeEvent{Kind::samples, 0xdead, {}, {{}}});
    const auto got = server_core::assemble_strokes(with_stray);
    ASSERT_EQ(got.size(), order.size());
    for (std::size_t i = 0; i < order.size(); ++i) expect_same(want[order[i]], got[i]);
  }
}

struct TempDir {
  std::filesystem::path dir;
  explicit TempDir(const std::string& name)
      : dir(std::filesystem::temp_directory_path() /
            ("dc_" + name + "_" + std::to_string(::getpid()))) {
    std::filesystem::create_directories(dir);
  }
  ~TempDir() { std::filesystem::remove_all(dir); }
  std::string file(const std::string& n) const { return (dir / n).string(); }
};

TEST(StrokeLog, WriterAppendsAndRecoversATornTail) {
  TempDir tmp("stroke_log");
  const std::string path = tmp.file("log.dcs");
  const auto events = random_events(4, 7);
  ASSERT_GE(events.size(), 6u);
  {
    auto w =
        server_core::StrokeLogWriter::open(path, false, server_core::FsyncPolicy::every_record);
    ASSERT_TRUE(w) << w.error().message;
    for (int i = 0; i < 3; ++i) ASSERT_TRUE(w->append(events[static_cast<std::size_t>(i)]));
    EXPECT_EQ(w->records_written(), 3u);
  }
  // Simulate a crash mid-append: half a record at the end.
  {
    const auto rec = server_core::encode_stroke_event(events[3]);
    std::ofstream f(path, std::ios::binary | std::ios::app);
    f.write(reinterpret_cast<const char*>(rec->data()),
            static_cast<std::streamsize>(rec->size() / 2));
  }
  auto torn = server_core::read_stroke_log_file(path);
  ASSERT_TRUE(torn);
  EXPECT_EQ(torn->events.size(), 3u);
  ASSERT_TRUE(torn->tail);
  {
    auto w = server_core::StrokeLogWriter::open(path, true, server_core::FsyncPolicy::on_flush);
    ASSERT_TRUE(w) << w.error().message;
    EXPECT_TRUE(w->recovered_tail());
    ASSERT_TRUE(w->append(events[4]));
    // A whole stroke is written as its begin and its end.
    ASSERT_TRUE(w->append(protocol::Stroke{42, events[0].brush, events[0].samples}));
    ASSERT_TRUE(w->close());
  }
  auto r = server_core::read_stroke_log_file(path);
  ASSERT_TRUE(r) << r.error().message;
  EXPECT_FALSE(r->tail);
  ASSERT_EQ(r->events.size(), 6u);
  for (int i = 0; i < 3; ++i)
    expect_same(events[static_cast<std::size_t>(i)], r->events[static_cast<std::size_t>(i)]);
  expect_same(r->events[3], events[4]);
  expect_same(r->events[4], StrokeEvent{Kind::begin, 42, events[0].brush, events[0].samples});
  expect_same(r->events[5], StrokeEvent{Kind::end, 42, {}, {}});
  EXPECT_FALSE(server_core::read_stroke_log_file(tmp.file("missing")));

  // Appending to a missing or empty file starts a new log.
  std::ofstream(tmp.file("empty")).flush();
  for (const char* name : {"missing", "empty"}) {
    auto w = server_core::StrokeLogWriter::open(tmp.file(name), true,
                                                server_core::FsyncPolicy::on_flush);
    ASSERT_TRUE(w) << name << ": " << w.error().message;
    ASSERT_TRUE(w->append(events[0]));
    ASSERT_TRUE(w->close());
    auto back = server_core::read_stroke_log_file(tmp.file(name));
    ASSERT_TRUE(back) << name;
    ASSERT_EQ(back->events.size(), 1u) << name;
  }
}

TEST(StrokeLog, WriterRefusesToAppendToAVersionOneLogAndLeavesItAlone) {
  TempDir tmp("stroke_log_v1");
  const std::string path = tmp.file("old.dcs");
  auto bytes = header(1);
  const auto rec = v1_record(random_strokes(1, 8)[0]);
  bytes.insert(bytes.end(), rec.begin(), rec.end());
  {
    std::ofstream f(path, std::ios::binary);
    f.write(reinterpret_cast<const char*>(bytes.data()),
            static_cast<std::streamsize>(bytes.size()));
  }
  auto w = server_core::StrokeLogWriter::open(path, true, server_core::FsyncPolicy::on_flush);
  ASSERT_FALSE(w);
  EXPECT_EQ(w.error().code, Errc::unsupported);
  EXPECT_NE(w.error().message.find("version-1"), std::string::npos) << w.error().message;
  auto after = paintings::read_file_bytes(path);
  ASSERT_TRUE(after);
  EXPECT_EQ(*after, bytes);

  // Something that is not a stroke log is refused too, naming the file.
  std::ofstream(tmp.file("text")) << "not a stroke log at all";
  auto t = server_core::StrokeLogWriter::open(tmp.file("text"), true,
                                              server_core::FsyncPolicy::on_flush);
  ASSERT_FALSE(t);
  EXPECT_NE(t.error().message.find(tmp.file("text")), std::string::npos);
}

// The recorder keeps what it wrote, and on its first error logs once, stops (a log with a gap
// would not replay to the canvas) and counts every event it drops; it never throws.
TEST(StrokeLog, RecorderStopsAtItsFirstErrorAndCountsWhatItDrops) {
  TempDir tmp("stroke_log_rec");
  std::ostringstream log_text;
  base::set_log_sink(std::make_shared<spdlog::sinks::ostream_sink_mt>(log_text));
  base::set_log_rate_limit(0);

  const auto events = random_events(3, 9);
  auto rec = server_core::StrokeLogRecorder::open(tmp.file("canvas.dcs"), "main");
  ASSERT_TRUE(rec) << rec.error().message;
  auto record = server_core::StrokeLogRecorder::callback(*rec);
  for (const auto& e : events) record(e);
  EXPECT_EQ((*rec)->events_written(), events.size());
  ASSERT_TRUE((*rec)->flush());
  auto r = server_core::read_stroke_log_file(tmp.file("canvas.dcs"));
  ASSERT_TRUE(r);
  EXPECT_EQ(r->events.size(), events.size());

  // An event too large for one record is a write error.
  StrokeEvent big{Kind::samples, events[0].stroke_id, {}, {}};
  big.samples.resize(server_core::kMaxRecordBytes / 36);
  record(big);
  big.samples.clear();
  record(big);
  record(events[0]);
  EXPECT_TRUE((*rec)->failed());
  EXPECT_EQ((*rec)->dropped(), 3u);
  EXPECT_EQ((*rec)->events_written(), events.size());
  EXPECT_TRUE((*rec)->flush());
  EXPECT_TRUE((*rec)->close());

  base::set_log_sink(nullptr);
  base::set_log_rate_limit(20);
  const std::string text = log_text.str();
  std::size_t lines = 0;
  for (auto at = text.find("event=stroke_log_failed"); at != std::string::npos;
       at = text.find("event=stroke_log_failed", at + 1))
    ++lines;
  EXPECT_EQ(lines, 1u) << text;
  EXPECT_NE(text.find("canvas=main"), std::string::npos) << text;

  auto after = server_core::read_stroke_log_file(tmp.file("canvas.dcs"));
  ASSERT_TRUE(after);
  EXPECT_FALSE(after->tail);
  EXPECT_EQ(after->events.size(), events.size());

  // Opened again (a restarted server), it continues the log.
  auto again = server_core::StrokeLogRecorder::open(tmp.file("canvas.dcs"), "main");
  ASSERT_TRUE(again);
  (*again)->record(events[0]);
  ASSERT_TRUE((*again)->close());
  auto continued = server_core::read_stroke_log_file(tmp.file("canvas.dcs"));
  ASSERT_TRUE(continued);
  EXPECT_EQ(continued->events.size(), events.size() + 1);
}

}  // namespace
}  // namespace deepcanvas
