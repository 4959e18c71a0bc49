#include "deepcanvas/server_core/stroke_log.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <bit>
#include <cerrno>
#include <cstring>

#include "deepcanvas/paintings/apa.hpp"

namespace deepcanvas::server_core {

namespace {

constexpr char kMagic[8] = {'D', 'C', 'S', 'T', 'R', 'O', 'K', 'E'};
constexpr std::size_t kFixedPayload = 8 + 1 + 16 + 4 + 4 + 4;  // id mode colour op hard n
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

}  // namespace

static_assert(kFixedPayload == 37);

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

std::vector<std::uint8_t> encode_stroke_record(const protocol::Stroke& s) {
  std::vector<std::uint8_t> b;
  const std::size_t payload = kFixedPayload + kSampleBytes * s.samples.size();
  b.reserve(12 + payload);
  put_u32(b, static_cast<std::uint32_t>(payload));
  put_u64(b, 0);  // checksum, filled below
  put_u64(b, s.id);
  b.push_back(static_cast<std::uint8_t>(s.brush.mode));
  for (float c : s.brush.colour) put_f32(b, c);
  put_f32(b, s.brush.opacity);
  put_f32(b, s.brush.hardness);
  put_u32(b, static_cast<std::uint32_t>(s.samples.size()));
  for (const auto& p : s.samples) {
    put_f64(b, p.x);
    put_f64(b, p.y);
    put_f64(b, p.z);
    put_f32(b, p.radius);
    put_f32(b, p.pressure);
    put_u32(b, p.t_ms);
  }
  std::uint64_t h = fnv1a64(std::span(b.data(), 4));
  h = fnv1a64(std::span(b.data() + 12, payload), h);
  for (int i = 0; i < 8; ++i) b[4 + i] = static_cast<std::uint8_t>(h >> (8 * i));
  return b;
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
  if (version != kStrokeLogVersion)
    return make_error(Errc::unsupported,
                      "offset 8: unsupported stroke log version " + std::to_string(version));
  StrokeLogContents out;
  std::size_t off = kStrokeLogHeaderBytes;
  out.valid_bytes = off;
  auto fail = [&](std::string reason) {
    out.tail = StrokeLogTail{off, std::move(reason)};
    return out;
  };
  while (off < bytes.size()) {
    const std::size_t left = bytes.size() - off;
    if (left < 12) return fail("torn record header: " + std::to_string(left) + " of 12 bytes");
    const std::uint8_t* r = bytes.data() + off;
    const std::uint32_t len = get_u32(r);
    if (len < kFixedPayload || len > kMaxRecordBytes || (len - kFixedPayload) % kSampleBytes != 0)
      return fail("corrupt record: impossible payload length " + std::to_string(len));
    if (left - 12 < len)
      return fail("torn record: " + std::to_string(left) + " of " + std::to_string(12 + len) +
                  " bytes");
    std::uint64_t h = fnv1a64(std::span(r, 4));
    h = fnv1a64(std::span(r + 12, len), h);
    if (h != get_u64(r + 4)) return fail("corrupt record: checksum mismatch");
    const std::uint8_t* p = r + 12;
    protocol::Stroke s;
    s.id = get_u64(p);
    const std::uint8_t mode = p[8];
    if (mode >= protocol::kBrushModeCount)
      return fail("corrupt record: unknown brush mode " + std::to_string(mode));
    s.brush.mode = static_cast<protocol::BrushMode>(mode);
    for (int i = 0; i < 4; ++i) s.brush.colour[i] = std::bit_cast<float>(get_u32(p + 9 + 4 * i));
    s.brush.opacity = std::bit_cast<float>(get_u32(p + 25));
    s.brush.hardness = std::bit_cast<float>(get_u32(p + 29));
    const std::uint32_t n = get_u32(p + 33);
    if (std::size_t{n} * kSampleBytes != len - kFixedPayload)
      return fail("corrupt record: sample count " + std::to_string(n) +
                  " does not match the payload length");
    s.samples.resize(n);
    const std::uint8_t* q = p + kFixedPayload;
    for (std::uint32_t i = 0; i < n; ++i, q += kSampleBytes) {
      auto& smp = s.samples[i];
      smp.x = std::bit_cast<double>(get_u64(q));
      smp.y = std::bit_cast<double>(get_u64(q + 8));
      smp.z = std::bit_cast<double>(get_u64(q + 16));
      smp.radius = std::bit_cast<float>(get_u32(q + 24));
      smp.pressure = std::bit_cast<float>(get_u32(q + 28));
      smp.t_ms = get_u32(q + 32);
    }
    out.strokes.push_back(std::move(s));
    off += 12 + len;
    out.valid_bytes = off;
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
    if (existing) {
      auto contents = read_stroke_log(*existing);
      if (!contents) return std::move(contents).error();
      w.recovered_ = contents->tail;
      w.fd_ = ::open(path.c_str(), O_WRONLY | O_APPEND | O_CLOEXEC);
      if (w.fd_ < 0) return sys_error(path + ": open");
      if (contents->tail && ::ftruncate(w.fd_, static_cast<off_t>(contents->valid_bytes)) != 0)
        return sys_error(path + ": truncating the torn tail");
      return w;
    }
    if (existing.error().code != Errc::not_found) return std::move(existing).error();
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

Result<void> StrokeLogWriter::append(const protocol::Stroke& stroke) {
  if (fd_ < 0) return make_error(Errc::invalid_argument, "stroke log writer is closed");
  const auto rec = encode_stroke_record(stroke);
  if (rec.size() - 12 > kMaxRecordBytes)
    return make_error(Errc::limit_exceeded, "stroke too large for one log record");
  auto r = write_all(fd_, rec.data(), rec.size(), path_);
  if (!r) return r;
  ++records_;
  if (policy_ == FsyncPolicy::every_record && ::fsync(fd_) != 0)
    return sys_error(path_ + ": fsync");
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

}  // namespace deepcanvas::server_core
