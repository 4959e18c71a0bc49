// The project's stroke log: a binary, versioned, append-only file of a canvas's stroke events
// (StrokeEvent: a stroke's begin, a batch of its samples, its end) in the order the canvas's
// painter took them, one checksummed record per event. Replaying the events in that order
// reproduces the canvas exactly, also when several artists' strokes were painted interleaved
// (`deepcanvas-server replay`; `deepcanvas-server serve --stroke-log` records a live canvas).
// It records order for replays; it is not yet the durable storage of the canvas.
//
// Layout, version 2 (written; all integers and floats little-endian, floats IEEE 754):
//   file header  8 bytes magic "DCSTROKE", u32 format version (2), u32 reserved (0)
//   record       u32 payload length L, u64 FNV-1a-64 of (the 4 length bytes + payload), payload
//   payload      u8 kind, u64 stroke id, then by kind:
//                  1 begin    u8 brush mode, 4 x f32 colour, f32 opacity, f32 hardness,
//                             u32 sample count n, n x sample          L = 38 + 36 n
//                  2 samples  u32 sample count n, n x sample          L = 13 + 36 n
//                  3 end      nothing                                 L = 9
//                  4 undo     nothing: stroke id is the stroke undone L = 9
//                  5 redo     nothing: stroke id is the stroke redone L = 9
//                  6 paste    an encoded CellPaste (cell_paste.hpp): an import's cells; its
//                             stroke id names it for undo               L = 9 + its bytes
//                (kinds 4 and 5 came with undo, 6 with import; a reader from before stops at
//                them as at an unknown kind, keeping every event before)
//   sample       3 x f64 position (canvas metres), f32 radius, f32 pressure, u32 t_ms (36 bytes)
// A record is at most kMaxRecordBytes. Stroke ids name strokes within one log (a canvas's ids);
// several of them may be open at once, so their events interleave.
//
// Version 1 (read, never written): the same header with version 1, the same record framing,
// and one record per whole stroke: payload u64 stroke id, u8 mode, 4 x f32 colour, f32 opacity,
// f32 hardness, u32 n, n x sample (L = 37 + 36 n). It reads as that stroke's begin (with all of
// its samples) followed by its end. A writer never appends to a version-1 file (open() refuses
// it): `deepcanvas-server replay OLD --log-out NEW` converts one.
//
// Untrusted input: the reader checks everything and never reads past the buffer. A log whose
// last record is torn (a crash mid-append) or corrupt is still useful: read_stroke_log() returns
// every event before the first bad record plus the offset and the reason of the bad one (a torn
// record, a checksum mismatch, an impossible length, an unknown kind or brush mode). An event is
// plain data: its brush and samples reach a canvas only through protocol::ValidatedStroke /
// ValidatedBrush / ValidatedSamples with the canvas's rules (e.g. Painter's plain overloads).
//
// Durability (fsync policy): StrokeLogWriter::append() writes a whole record with one write(2)
// on an O_APPEND descriptor, so a crash leaves at most one torn record at the tail. With
// FsyncPolicy::every_record it fsyncs before returning (the record survives power loss);
// with FsyncPolicy::on_flush only flush() and close/destruction fsync (batching for replays).
// Threading: a writer is used by one thread at a time; StrokeLogRecorder is thread-safe.
#pragma once

#include <atomic>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "deepcanvas/base/result.hpp"
#include "deepcanvas/protocol/stroke.hpp"

namespace deepcanvas::server_core {

inline constexpr std::uint32_t kStrokeLogVersion = 2;  // the version writers write
inline constexpr std::size_t kStrokeLogHeaderBytes = 16;
inline constexpr std::size_t kMaxRecordBytes = 64u << 20;

// One step of a canvas's painting in the order its painter took it. A canvas paints several
// artists' strokes interleaved, batch by batch (canvas_service.hpp, "Stroke order"); replaying
// its events in order, each painted to completion before the next (Painter: begin_stroke,
// add_samples, end_stroke, then step() until it returns false), reproduces its canvas exactly.
// An undo (redo) event takes back (restores) stroke `stroke_id` as a Painter::revert() of its
// recorded change (undo_history.hpp); replaying it needs that stroke's events before it. A paste
// event (an import) is one whole operation: Painter::paste() of its cells, with its own id.
struct StrokeEvent {
  enum class Kind : std::uint8_t { begin = 1, samples = 2, end = 3, undo = 4, redo = 5, paste = 6 };
  Kind kind = Kind::begin;
  std::uint64_t stroke_id = 0;
  protocol::Brush brush;                        // begin only
  std::vector<protocol::StrokeSample> samples;  // begin and samples
  std::vector<std::uint8_t> paste{};            // paste only: the encoded CellPaste (untrusted)
  // Who sent it (CanvasService's artist key; 0 when unknown). Not in the stroke log file: the
  // canvas's durable history keeps it per event (storage), and replays use it for the undo
  // history's per-artist bounds.
  std::uint64_t artist = 0;
  // When it was recorded (unix milliseconds; 0 when unknown). Not in the stroke log file either:
  // the durable history keeps it per event (history playback's painting time).
  std::int64_t time_ms = 0;
  // Begin only: the sender's handle for the stroke, where the artist is a client id's (0:
  // none). With the artist it names the stroke across a restart (StrokeName). Not in the stroke
  // log file either: the durable history keeps it.
  std::uint64_t handle = 0;
};

// A stroke named the way its sender names it: the artist key its client id gives and the handle
// it sent the stroke with. The durable history keeps the names of strokes whose end is durable,
// so that after a restart a resend of one (a client that missed its answer) is answered as it
// was, with the stroke or, for one a limit stopped, with limit_exceeded, instead of painting
// it again (server_net StrokeReceipts).
struct StrokeName {
  std::uint64_t artist = 0;
  std::uint64_t handle = 0;
  std::uint64_t stroke_id = 0;
  bool stopped = false;  // ended after a limit stopped it (EndedBy::stopped): answered with the error
};

std::uint64_t fnv1a64(std::span<const std::uint8_t> bytes,
                      std::uint64_t seed = 0xcbf29ce484222325ull) noexcept;

// The file header bytes (version kStrokeLogVersion).
std::vector<std::uint8_t> stroke_log_header();
// One whole version-2 record (length, checksum, payload) for `event`. limit_exceeded when it
// would pass kMaxRecordBytes.
Result<std::vector<std::uint8_t>> encode_stroke_event(const StrokeEvent& event);
// A whole stroke as events: its begin (with every sample) and its end.
std::vector<StrokeEvent> stroke_events(const protocol::Stroke& stroke);

struct StrokeLogTail {
  std::uint64_t offset = 0;  // where the bad record starts
  std::string reason;        // e.g. "torn record: 12 of 80 bytes", "checksum mismatch"
};

struct StrokeLogContents {
  std::uint32_t version = 0;  // of the file (1 or 2)
  std::vector<StrokeEvent> events;
  std::uint64_t valid_bytes = 0;      // header + every good record
  std::optional<StrokeLogTail> tail;  // set when the log ends in a torn or corrupt record
};

// Errors (Errc::malformed / unsupported) only for a bad file header; a bad record is reported
// in `tail` and ends the read.
Result<StrokeLogContents> read_stroke_log(std::span<const std::uint8_t> bytes);
Result<StrokeLogContents> read_stroke_log_file(const std::string& path);
// Cheap sniffing for tools that accept several input kinds.
bool looks_like_stroke_log(std::span<const std::uint8_t> bytes) noexcept;

// For tools that want whole strokes rather than the painting order (export, statistics): each
// stroke with its brush and all of its samples, in the order of the strokes' begins. Events for
// a stroke id with no begin before them are skipped; a stroke whose end is missing is included
// with the samples it has. Painting these strokes one after another gives the recorded canvas
// only where no two strokes were open at once over the same cells; replay the events for that.
std::vector<protocol::Stroke> assemble_strokes(std::span<const StrokeEvent> events);

enum class FsyncPolicy { every_record, on_flush };

class StrokeLogWriter {
 public:
  // Creates the file (truncating) or, with `append`, opens an existing log, checks it and cuts
  // off a torn/corrupt tail so new records follow the last good one (the cut is reported in
  // `recovered_tail()`). unsupported for an existing version-1 log (records of two layouts
  // must not mix in one file).
  static Result<StrokeLogWriter> open(const std::string& path, bool append, FsyncPolicy policy);
  StrokeLogWriter(StrokeLogWriter&&) noexcept;
  StrokeLogWriter& operator=(StrokeLogWriter&&) noexcept;
  ~StrokeLogWriter();

  Result<void> append(const StrokeEvent& event);
  // The stroke's begin (with every sample) and its end, as two records.
  Result<void> append(const protocol::Stroke& stroke);
  Result<void> flush();  // fsync
  Result<void> close();
  const std::optional<StrokeLogTail>& recovered_tail() const noexcept { return recovered_; }
  std::uint64_t records_written() const noexcept { return records_; }
  const std::string& path() const noexcept { return path_; }

 private:
  StrokeLogWriter() = default;
  int fd_ = -1;
  FsyncPolicy policy_ = FsyncPolicy::on_flush;
  std::optional<StrokeLogTail> recovered_;
  std::uint64_t records_ = 0;
  std::string path_;
};

// Records a live canvas's stroke order: CanvasServiceConfig::on_stroke_event appends each event
// to a log (FsyncPolicy::on_flush, appending to an existing log so a restarted server continues
// it). It runs on the canvas's stroke thread, so it never throws and never stops that thread:
// the first write error is logged (event stroke_log_failed) and ends the recording, because a
// log with a gap no longer replays to the canvas; every event not written after that is counted
// in dropped(). Flush at shutdown, after the canvas has stopped.
// Threading: record() and the other members may be called from any thread (one mutex).
class StrokeLogRecorder {
 public:
  // Opens (or creates) the log; the errors of StrokeLogWriter::open. `canvas` names the canvas
  // in log lines.
  static Result<std::shared_ptr<StrokeLogRecorder>> open(const std::string& path,
                                                         std::string canvas);
  void record(const StrokeEvent& event) noexcept;
  // A callback for CanvasServiceConfig::on_stroke_event (it shares ownership of the recorder).
  static std::function<void(const StrokeEvent&)> callback(std::shared_ptr<StrokeLogRecorder> r);
  Result<void> flush();
  Result<void> close();
  std::uint64_t events_written() const noexcept { return written_.load(); }
  std::uint64_t dropped() const noexcept { return dropped_.load(); }
  bool failed() const noexcept { return failed_.load(); }
  const std::optional<StrokeLogTail>& recovered_tail() const noexcept { return recovered_; }
  const std::string& canvas() const noexcept { return canvas_; }

 private:
  StrokeLogRecorder(StrokeLogWriter writer, std::string canvas);
  std::mutex mutex_;
  std::optional<StrokeLogWriter> writer_;  // reset on the first error and on close()
  std::string canvas_;
  std::optional<StrokeLogTail> recovered_;
  std::atomic<std::uint64_t> written_{0}, dropped_{0};
  std::atomic<bool> failed_{false};
};

}  // namespace deepcanvas::server_core
