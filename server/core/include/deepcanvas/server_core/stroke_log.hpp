// The project's stroke log: a binary, versioned, append-only file of strokes, one checksummed
// record per stroke. Used by replays (`deepcanvas-server replay --log-out`) and for persistence.
//
// Layout (little-endian):
//   file header  8 bytes magic "DCSTROKE", u32 format version (1), u32 reserved (0)
//   record       u32 payload length L, u64 FNV-1a-64 of (the 4 length bytes + payload), payload
//   payload      u64 stroke id, u8 mode, 4 x f32 colour, f32 opacity, f32 hardness,
//                u32 sample count n, n x (3 x f64 position, f32 radius, f32 pressure, u32 t_ms)
// L must equal 37 + 36 n; a record is at most kMaxRecordBytes.
//
// Untrusted input: the reader checks everything and never reads past the buffer. A log whose
// last record is torn (a crash mid-append) or corrupt is still useful: read_stroke_log() returns
// every record before the first bad one plus the offset and the reason of the bad one. A record
// is a plain protocol::Stroke: it reaches a canvas only through protocol::ValidatedStroke::make
// with the canvas's rules (e.g. Painter's plain-stroke overloads).
//
// Durability (fsync policy): StrokeLogWriter::append() writes a whole record with one write(2)
// on an O_APPEND descriptor, so a crash leaves at most one torn record at the tail. With
// FsyncPolicy::every_record it fsyncs before returning (the record survives power loss);
// with FsyncPolicy::on_flush only flush() and close/destruction fsync (batching for replays).
// Threading: a writer is used by one thread at a time.
#pragma once

#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "deepcanvas/base/result.hpp"
#include "deepcanvas/protocol/stroke.hpp"

namespace deepcanvas::server_core {

inline constexpr std::uint32_t kStrokeLogVersion = 1;
inline constexpr std::size_t kStrokeLogHeaderBytes = 16;
inline constexpr std::size_t kMaxRecordBytes = 64u << 20;

// One step of a canvas's painting in the order its painter took it. A canvas paints several
// artists' strokes interleaved, batch by batch (canvas_service.hpp, "Stroke order"); replaying
// its events in order, each painted to completion before the next (Painter: begin_stroke,
// add_samples, end_stroke, then step() until it returns false), reproduces its canvas exactly.
struct StrokeEvent {
  enum class Kind : std::uint8_t { begin = 1, samples = 2, end = 3 };
  Kind kind = Kind::begin;
  std::uint64_t stroke_id = 0;
  protocol::Brush brush;                        // begin only
  std::vector<protocol::StrokeSample> samples;  // begin and samples
};

std::uint64_t fnv1a64(std::span<const std::uint8_t> bytes,
                      std::uint64_t seed = 0xcbf29ce484222325ull) noexcept;

// The file header bytes.
std::vector<std::uint8_t> stroke_log_header();
// One whole record (length, checksum, payload) for `stroke`.
std::vector<std::uint8_t> encode_stroke_record(const protocol::Stroke& stroke);

struct StrokeLogTail {
  std::uint64_t offset = 0;  // where the bad record starts
  std::string reason;        // e.g. "torn record: 12 of 80 bytes", "checksum mismatch"
};

struct StrokeLogContents {
  std::vector<protocol::Stroke> strokes;
  std::uint64_t valid_bytes = 0;      // header + every good record
  std::optional<StrokeLogTail> tail;  // set when the log ends in a torn or corrupt record
};

// Errors (Errc::malformed / unsupported) only for a bad file header; a bad record is reported
// in `tail` and ends the read.
Result<StrokeLogContents> read_stroke_log(std::span<const std::uint8_t> bytes);
Result<StrokeLogContents> read_stroke_log_file(const std::string& path);
// Cheap sniffing for tools that accept several input kinds.
bool looks_like_stroke_log(std::span<const std::uint8_t> bytes) noexcept;

enum class FsyncPolicy { every_record, on_flush };

class StrokeLogWriter {
 public:
  // Creates the file (truncating) or, with `append`, opens an existing log, checks it and cuts
  // off a torn/corrupt tail so new records follow the last good one (the cut is reported in
  // `recovered_tail()`).
  static Result<StrokeLogWriter> open(const std::string& path, bool append, FsyncPolicy policy);
  StrokeLogWriter(StrokeLogWriter&&) noexcept;
  StrokeLogWriter& operator=(StrokeLogWriter&&) noexcept;
  ~StrokeLogWriter();

  Result<void> append(const protocol::Stroke& stroke);
  Result<void> flush();  // fsync
  Result<void> close();
  const std::optional<StrokeLogTail>& recovered_tail() const noexcept { return recovered_; }
  std::uint64_t records_written() const noexcept { return records_; }

 private:
  StrokeLogWriter() = default;
  int fd_ = -1;
  FsyncPolicy policy_ = FsyncPolicy::on_flush;
  std::optional<StrokeLogTail> recovered_;
  std::uint64_t records_ = 0;
  std::string path_;
};

}  // namespace deepcanvas::server_core
