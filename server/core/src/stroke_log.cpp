#include "deepcanvas/server_core/stroke_log.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <bit>
#include <cerrno>
#include <cstring>
#include <unordered_map>

#include "deepcanvas/base/log.hpp"
#include "deepcanvas/paintings/apa.hpp"

namespace deepcanvas::server_core {

namespace {

constexpr char kMagic[8] = {'D', 'C', 'S', 'T', 'R', 'O', 'K', 'E'};
constexpr std::size_t kFixedPayload = 8 + 1 + 16 + 4 + 4 + 4;  // version 1: id brush n
constexpr std::size_t kSampleBytes = 3 * 8 + 4 + 4 + 4;

void put_u32(std::vector<std::uint8_t>& b, std::uint32_t v) {
  for (int i = 0; i < 4; ++i) b.push_back(static_cast<std::uint8_t>(v >> (8 * i)));
}
void put_u64(std::vector<std::uint8_t>& b, std::uint64_t v) {
  for (int i = 0; i < 8; ++i) b.push_back(static_cast<std::uint8_t>(v >> (8 * i)));
}
void put_f32(std::vector<std::uint8_t>& b, float v) {
  put_u32(b, std::bit_cast<std::uint32_t>(v));
}
void put_f64(std::vector<std::uint8_t>& b, double v) {
  put_u64(b, std::bit_cast<std::uint64_t>(v));
}
std::uint32_t get_u32(const std::uint8_t* p) {
  return std::uint32_t{p[0]} | (std::uint32_t{p[1]} << 8) | (std::uint32_t{p[2]} << 16) |
         (std::uint32_t{p[3]} << 24);
}
std::uint64_t get_u64(const std::uint8_t* p) {
  return std::uint64_t{get_u32(p)} | (std::uint64_t{get_u32(p + 4)} << 32);
}

Error sys_error(const std::string& what) {
  return make_error(Errc::io_error, what + ": " + std::strerror(errno));
}

Result<void> write_all(int fd, const std::uint8_t* p, std::size_t n, const std::string& path) {
  while (n > 0) {
    const ssize_t w = ::write(fd, p, n);
    if (w < 0) {
      if (errno == EINTR) continue;
      return sys_error(path + ": write");
    }
    p += w;
    n -= static_cast<std::size_t>(w);
  }
  return {};
}

constexpr std::size_t kEventHead = 1 + 8;            // kind, stroke id
constexpr std::size_t kBrushBytes = 1 + 16 + 4 + 4;  // mode colour opacity hardness
static_assert(kFixedPayload == 37 && kBrushBytes + 4 + 8 == kFixedPayload);

void put_brush(std::vector<std::uint8_t>& b, const protocol::Brush& brush) {
  b.push_back(static_cast<std::uint8_t>(brush.mode));
  for (float c : brush.colour) put_f32(b, c);
  put_f32(b, brush.opacity);
  put_f32(b, brush.hardness);
}

void put_samples(std::vector<std::uint8_t>& b, std::span<const protocol::StrokeSample> samples) {
  put_u32(b, static_cast<std::uint32_t>(samples.size()));
  for (const auto& p : samples) {
    put_f64(b, p.x);
    put_f64(b, p.y);
    put_f64(b, p.z);
    put_f32(b, p.radius);
    put_f32(b, p.pressure);
    put_u32(b, p.t_ms);
  }
}

// Reads a brush at p (kBrushBytes); false for an unknown mode.
bool get_brush(const std::uint8_t* p, protocol::Brush& brush) {
  if (p[0] >= protocol::kBrushModeCount) return false;
  brush.mode = static_cast<protocol::BrushMode>(p[0]);
  for (int i = 0; i < 4; ++i) brush.colour[i] = std::bit_cast<float>(get_u32(p + 1 + 4 * i));
  brush.opacity = std::bit_cast<float>(get_u32(p + 17));
  brush.hardness = std::bit_cast<float>(get_u32(p + 21));
  return true;
}

// Reads a sample count at p and the samples after it; `bytes` is what the record has left
// there. An error reason when the count does not match.
std::optional<std::string> get_samples(const std::uint8_t* p, std::size_t bytes,
                                       std::vector<protocol::StrokeSample>& out) {
  const std::uint32_t n = get_u32(p);
  if (std::size_t{n} * kSampleBytes != bytes - 4)
    return "corrupt record: sample count " + std::to_string(n) +
           " does not match the payload length";
  out.resize(n);
  const std::uint8_t* q = p + 4;
  for (std::uint32_t i = 0; i < n; ++i, q += kSampleBytes) {
    auto& smp = out[i];
    smp.x = std::bit_cast<double>(get_u64(q));
    smp.y = std::bit_cast<double>(get_u64(q + 8));
    smp.z = std::bit_cast<double>(get_u64(q + 16));
    smp.radius = std::bit_cast<float>(get_u32(q + 24));
    smp.pressure = std::bit_cast<float>(get_u32(q + 28));
    smp.t_ms = get_u32(q + 32);
  }
  return std::nullopt;
}

// The payload length a version-2 record of `kind` with n samples has.
std::size_t v2_payload_bytes(StrokeEvent::Kind kind, std::size_t n) {
  switch (kind) {
    case StrokeEvent::Kind::begin:
      return kEventHead + kBrushBytes + 4 + kSampleBytes * n;
    case StrokeEvent::Kind::samples:
      return kEventHead + 4 + kSampleBytes * n;
    case StrokeEvent::Kind::end:
    case StrokeEvent::Kind::undo:
    case StrokeEvent::Kind::redo:
      return kEventHead;
    case StrokeEvent::Kind::paste:
      return kEventHead + n;  // n: the paste's bytes
  }
  return 0;
}

// Decodes one checked payload (its checksum matched) into events; an error reason otherwise.
std::optional<std::string> decode_v1(const std::uint8_t* p, std::size_t len,
                                     std::vector<StrokeEvent>& out) {
  if (len < kFixedPayload || (len - kFixedPayload) % kSampleBytes != 0)
    return "corrupt record: impossible payload length " + std::to_string(len);
  StrokeEvent begin;
  begin.stroke_id = get_u64(p);
  if (!get_brush(p + 8, begin.brush))
    return "corrupt record: unknown brush mode " + std::to_string(p[8]);
  if (auto bad = get_samples(p + 8 + kBrushBytes, len - 8 - kBrushBytes, begin.samples)) return bad;
  StrokeEvent end;
  end.kind = StrokeEvent::Kind::end;
  end.stroke_id = begin.stroke_id;
  out.push_back(std::move(begin));
  out.push_back(std::move(end));
  return std::nullopt;
}

std::optional<std::string> decode_v2(const std::uint8_t* p, std::size_t len,
                                     std::vector<StrokeEvent>& out) {
  if (len < kEventHead) return "corrupt record: impossible payload length " + std::to_string(len);
  StrokeEvent e;
  const std::uint8_t kind = p[0];
  e.stroke_id = get_u64(p + 1);
  const std::uint8_t* body = p + kEventHead;
  const std::size_t body_bytes = len - kEventHead;
  switch (kind) {
    case 1:
      e.kind = StrokeEvent::Kind::begin;
      if (body_bytes < kBrushBytes + 4)
        return "corrupt record: begin payload of " + std::to_string(len) + " bytes (at least 38)";
      if (!get_brush(body, e.brush))
        return "corrupt record: unknown brush mode " + std::to_string(body[0]);
      if (auto bad = get_samples(body + kBrushBytes, body_bytes - kBrushBytes, e.samples))
        return bad;
      break;
    case 2:
      e.kind = StrokeEvent::Kind::samples;
      if (body_bytes < 4)
        return "corrupt record: samples payload of " + std::to_string(len) + " bytes (at least 13)";
      if (auto bad = get_samples(body, body_bytes, e.samples)) return bad;
      break;
    case 3:
    case 4:
    case 5:
      e.kind = static_cast<StrokeEvent::Kind>(kind);
      if (body_bytes != 0)
        return "corrupt record: payload of " + std::to_string(len) + " bytes for event kind " +
               std::to_string(kind) + " (exactly 9)";
      break;
    case 6:
      e.kind = StrokeEvent::Kind::paste;
      if (body_bytes == 0) return "corrupt record: a paste event with no cells";
      e.paste.assign(body, body + body_bytes);
      break;
    default:
      return "corrupt record: unknown event kind " + std::to_string(kind);
  }
  out.push_back(std::move(e));
  return std::nullopt;
}

}  // namespace

std::uint64_t fnv1a64(std::span<const std::uint8_t> bytes, std::uint64_t h) noexcept {
  for (std::uint8_t b : bytes) {
    h ^= b;
    h *= 0x100000001b3ull;
  }
  return h;
}

std::vector<std::uint8_t> stroke_log_header() {
  std::vector<std::uint8_t> b(kMagic, kMagic + 8);
  put_u32(b, kStrokeLogVersion);
  put_u32(b, 0);
  return b;
}

Result<std::vector<std::uint8_t>> encode_stroke_event(const StrokeEvent& e) {
  const bool has_samples =
      e.kind == StrokeEvent::Kind::begin || e.kind == StrokeEvent::Kind::samples;
  const bool is_paste = e.kind == StrokeEvent::Kind::paste;
  const std::size_t n = has_samples ? e.samples.size() : is_paste ? e.paste.size() : 0;
  if (is_paste && (n == 0 || n > kMaxRecordBytes - kEventHead))
    return make_error(Errc::limit_exceeded, "a paste event of " + std::to_string(n) +
                                                " bytes does not fit one log record");
  // Checked before multiplying so that no count can wrap the length.
  if (!is_paste && (n > kMaxRecordBytes / kSampleBytes || v2_payload_bytes(e.kind, n) > kMaxRecordBytes))
    return make_error(Errc::limit_exceeded, "stroke event with " + std::to_string(n) +
                                                " samples is too large for one log record");
  const std::size_t payload = v2_payload_bytes(e.kind, n);
  std::vector<std::uint8_t> b;
  b.reserve(12 + payload);
  put_u32(b, static_cast<std::uint32_t>(payload));
  put_u64(b, 0);  // checksum, filled below
  b.push_back(static_cast<std::uint8_t>(e.kind));
  put_u64(b, e.stroke_id);
  if (e.kind == StrokeEvent::Kind::begin) put_brush(b, e.brush);
  if (has_samples) put_samples(b, e.samples);
  if (is_paste) b.insert(b.end(), e.paste.begin(), e.paste.end());
  std::uint64_t h = fnv1a64(std::span(b.data(), 4));
  h = fnv1a64(std::span(b.data() + 12, payload), h);
  for (int i = 0; i < 8; ++i) b[4 + i] = static_cast<std::uint8_t>(h >> (8 * i));
  return b;
}

std::vector<StrokeEvent> stroke_events(const protocol::Stroke& stroke) {
  std::vector<StrokeEvent> out(2);
  out[0].kind = StrokeEvent::Kind::begin;
  out[0].stroke_id = stroke.id;
  out[0].brush = stroke.brush;
  out[0].samples = stroke.samples;
  out[1].kind = StrokeEvent::Kind::end;
  out[1].stroke_id = stroke.id;
  return out;
}

bool looks_like_stroke_log(std::span<const std::uint8_t> bytes) noexcept {
  return bytes.size() >= 8 && std::memcmp(bytes.data(), kMagic, 8) == 0;
}

Result<StrokeLogContents> read_stroke_log(std::span<const std::uint8_t> bytes) {
  if (bytes.size() < kStrokeLogHeaderBytes)
    return make_error(Errc::malformed, "offset 0: truncated stroke log header (" +
                                           std::to_string(bytes.size()) + " of 16 bytes)");
  if (!looks_like_stroke_log(bytes))
    return make_error(Errc::malformed, "offset 0: bad magic (not a deepcanvas stroke log)");
  const std::uint32_t version = get_u32(bytes.data() + 8);
  if (version != 1 && version != 2)
    return make_error(Errc::unsupported,
                      "offset 8: unsupported stroke log version " + std::to_string(version));
  StrokeLogContents out;
  out.version = version;
  std::size_t off = kStrokeLogHeaderBytes;
  out.valid_bytes = off;
  auto fail = [&](std::string reason) -> StrokeLogContents {
    out.tail = StrokeLogTail{off, std::move(reason)};
    return std::move(out);
  };
  const std::size_t min_payload = version == 1 ? kFixedPayload : kEventHead;
  while (off < bytes.size()) {
    const std::size_t left = bytes.size() - off;
    if (left < 12) return fail("torn record header: " + std::to_string(left) + " of 12 bytes");
    const std::uint8_t* r = bytes.data() + off;
    const std::uint32_t len = get_u32(r);
    if (len < min_payload || len > kMaxRecordBytes)
      return fail("corrupt record: impossible payload length " + std::to_string(len));
    if (left - 12 < len)
      return fail("torn record: " + std::to_string(left) + " of " + std::to_string(12 + len) +
                  " bytes");
    std::uint64_t h = fnv1a64(std::span(r, 4));
    h = fnv1a64(std::span(r + 12, len), h);
    if (h != get_u64(r + 4)) return fail("corrupt record: checksum mismatch");
    // A record's events are added whole or not at all.
    std::vector<StrokeEvent> events;
    auto bad = version == 1 ? decode_v1(r + 12, len, events) : decode_v2(r + 12, len, events);
    if (bad) return fail(std::move(*bad));
    for (auto& e : events) out.events.push_back(std::move(e));
    off += 12 + len;
    out.valid_bytes = off;
  }
  return out;
}

std::vector<protocol::Stroke> assemble_strokes(std::span<const StrokeEvent> events) {
  std::vector<protocol::Stroke> out;
  std::unordered_map<std::uint64_t, std::size_t> open;  // stroke id -> index in out
  for (const auto& e : events) {
    if (e.kind == StrokeEvent::Kind::begin) {
      protocol::Stroke s;
      s.id = e.stroke_id;
      s.brush = e.brush;
      s.samples = e.samples;
      open[e.stroke_id] = out.size();
      out.push_back(std::move(s));
      continue;
    }
    if (e.kind == StrokeEvent::Kind::undo || e.kind == StrokeEvent::Kind::redo ||
        e.kind == StrokeEvent::Kind::paste)
      continue;
    const auto it = open.find(e.stroke_id);
    if (it == open.end()) continue;
    if (e.kind == StrokeEvent::Kind::samples) {
      auto& dst = out[it->second].samples;
      dst.insert(dst.end(), e.samples.begin(), e.samples.end());
    } else {
      open.erase(it);
    }
  }
  return out;
}

Result<StrokeLogContents> read_stroke_log_file(const std::string& path) {
  auto bytes = paintings::read_file_bytes(path);
  if (!bytes) return std::move(bytes).error();
  auto r = read_stroke_log(*bytes);
  if (!r) {
    Error e = std::move(r).error();
    e.message = path + ": " + e.message;
    return e;
  }
  return r;
}

Result<StrokeLogWriter> StrokeLogWriter::open(const std::string& path, bool append,
                                              FsyncPolicy policy) {
  StrokeLogWriter w;
  w.policy_ = policy;
  w.path_ = path;
  if (append) {
    auto existing = paintings::read_file_bytes(path);
    // An empty file (created, then a crash before its header) is started afresh.
    if (existing && !existing->empty()) {
      auto contents = read_stroke_log(*existing);
      if (!contents) return Error{contents.error().code, path + ": " + contents.error().message};
      if (contents->version != kStrokeLogVersion)
        return make_error(Errc::unsupported,
                          path + ": a version-" + std::to_string(contents->version) +
                              " stroke log cannot be appended to (convert it with "
                              "`deepcanvas-server replay FILE --log-out NEW`)");
      w.recovered_ = contents->tail;
      w.fd_ = ::open(path.c_str(), O_WRONLY | O_APPEND | O_CLOEXEC);
      if (w.fd_ < 0) return sys_error(path + ": open");
      if (contents->tail && ::ftruncate(w.fd_, static_cast<off_t>(contents->valid_bytes)) != 0)
        return sys_error(path + ": truncating the torn tail");
      return w;
    }
    if (!existing && existing.error().code != Errc::not_found) return std::move(existing).error();
  }
  w.fd_ = ::open(path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_APPEND | O_CLOEXEC, 0644);
  if (w.fd_ < 0) return sys_error(path + ": create");
  const auto header = stroke_log_header();
  auto r = write_all(w.fd_, header.data(), header.size(), path);
  if (!r) return std::move(r).error();
  if (policy == FsyncPolicy::every_record && ::fsync(w.fd_) != 0)
    return sys_error(path + ": fsync");
  return w;
}

StrokeLogWriter::StrokeLogWriter(StrokeLogWriter&& o) noexcept
    : fd_(o.fd_),
      policy_(o.policy_),
      recovered_(std::move(o.recovered_)),
      records_(o.records_),
      path_(std::move(o.path_)) {
  o.fd_ = -1;
}

StrokeLogWriter& StrokeLogWriter::operator=(StrokeLogWriter&& o) noexcept {
  if (this != &o) {
    (void)close();
    fd_ = o.fd_;
    policy_ = o.policy_;
    recovered_ = std::move(o.recovered_);
    records_ = o.records_;
    path_ = std::move(o.path_);
    o.fd_ = -1;
  }
  return *this;
}

StrokeLogWriter::~StrokeLogWriter() {
  (void)close();
}

Result<void> StrokeLogWriter::append(const StrokeEvent& event) {
  if (fd_ < 0) return make_error(Errc::invalid_argument, "stroke log writer is closed");
  auto rec = encode_stroke_event(event);
  if (!rec) return std::move(rec).error();
  auto r = write_all(fd_, rec->data(), rec->size(), path_);
  if (!r) return r;
  ++records_;
  if (policy_ == FsyncPolicy::every_record && ::fsync(fd_) != 0)
    return sys_error(path_ + ": fsync");
  return {};
}

Result<void> StrokeLogWriter::append(const protocol::Stroke& stroke) {
  for (const auto& e : stroke_events(stroke))
    if (auto r = append(e); !r) return r;
  return {};
}

Result<void> StrokeLogWriter::flush() {
  if (fd_ < 0) return {};
  if (::fsync(fd_) != 0) return sys_error(path_ + ": fsync");
  return {};
}

Result<void> StrokeLogWriter::close() {
  if (fd_ < 0) return {};
  auto r = flush();
  ::close(fd_);
  fd_ = -1;
  return r;
}

// ---- StrokeLogRecorder ----

StrokeLogRecorder::StrokeLogRecorder(StrokeLogWriter writer, std::string canvas)
    : canvas_(std::move(canvas)), recovered_(writer.recovered_tail()) {
  writer_.emplace(std::move(writer));
}

Result<std::shared_ptr<StrokeLogRecorder>> StrokeLogRecorder::open(const std::string& path,
                                                                   std::string canvas) {
  auto w = StrokeLogWriter::open(path, true, FsyncPolicy::on_flush);
  if (!w) return std::move(w).error();
  return std::shared_ptr<StrokeLogRecorder>(
      new StrokeLogRecorder(std::move(*w), std::move(canvas)));
}

void StrokeLogRecorder::record(const StrokeEvent& event) noexcept {
  std::string error;
  {
    std::lock_guard lock(mutex_);
    if (!writer_) {
      dropped_.fetch_add(1);
      return;
    }
    try {
      auto r = writer_->append(event);
      if (r) {
        written_.fetch_add(1);
        return;
      }
      error = r.error().message;
    } catch (...) {  // bad_alloc while encoding; `error` stays empty
    }
    // A log with a gap no longer replays to the canvas: stop here (a torn record at the tail is
    // cut off when the log is opened again).
    writer_.reset();
    failed_.store(true);
    dropped_.fetch_add(1);
  }
  try {
    base::log_event(base::LogLevel::error, "stroke_log_failed",
                    {{"canvas", canvas_},
                     {"error", error.empty() ? "out of memory encoding the record" : error},
                     {"stroke_id", event.stroke_id},
                     {"written", written_.load()},
                     {"effect", "recording stopped"}});
  } catch (...) {  // the stroke thread goes on; dropped() and failed() still tell
  }
}

std::function<void(const StrokeEvent&)> StrokeLogRecorder::callback(
    std::shared_ptr<StrokeLogRecorder> r) {
  return [r = std::move(r)](const StrokeEvent& e) { r->record(e); };
}

Result<void> StrokeLogRecorder::flush() {
  std::lock_guard lock(mutex_);
  if (!writer_) return {};
  return writer_->flush();
}

Result<void> StrokeLogRecorder::close() {
  std::lock_guard lock(mutex_);
  if (!writer_) return {};
  auto r = writer_->close();
  writer_.reset();
  return r;
}

}  // namespace deepcanvas::server_core
