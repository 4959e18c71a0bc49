// CellDiff: what one operation on the canvas (a stroke, an undo, a redo) changed, cell by cell,
// as the Painter records it (PainterConfig::record_diffs) and as Painter::revert() takes it
// back. It is what undo and redo are built on (undo_history.hpp; PROTOCOL.md 3.10).
//
// A change names a cell by its exact address (CellCoord, not its pool index: indices are reused
// after merges, addresses are not) and holds the cell's state before the operation and after it:
// whether the cell existed, whether it was a leaf, and its colour (RGBA8; internal cells keep a
// colour too: the filtered value of octree.hpp, which the tree refreshes itself afterwards). Cells
// the operation created have before.exists false; cells it freed (merged away) have after.exists
// false. Only cells whose state differs are kept, each once, in depth order (parents come before
// their children), within a depth in the order the operation first changed them.
//
// Encoded form (encode_cell_diff; what the undo history keeps in memory and checkpoints hold):
// zstd frame of
//   u32 magic "DCDF", u32 version (1), u64 n,
//   n x u8 depth, n x u32 x, n x u32 y, n x u32 z, n x u8 flags (bit 0 before.exists, 1
//   before.leaf, 2 after.exists, 3 after.leaf), n x u32 before colour, n x u32 after colour
// (little-endian, columns so that zstd finds the runs). About 2 to 6 bytes per changed cell.
//
// Untrusted input: decode_cell_diff() checks sizes, the magic, the version, depths and
// coordinates against the canvas (OctreeConfig), the depth order, and each state's consistency;
// it never reads past the buffer and returns malformed naming the field. (A cell listed twice
// is not refused: revert() uses its first change.)
#pragma once

#include <cstdint>
#include <memory>
#include <span>
#include <vector>

#include "deepcanvas/base/result.hpp"
#include "deepcanvas/server_core/octree.hpp"

namespace deepcanvas::server_core {

struct CellState {
  std::uint32_t colour = 0;  // RGBA8 (meaningless when !exists)
  bool exists = false;
  bool leaf = false;
  friend bool operator==(const CellState&, const CellState&) = default;
};

struct CellChange {
  CellCoord cell;
  CellState before, after;
};

struct CellDiff {
  std::vector<CellChange> changes;  // in depth order; before != after for each
  // The operation changed more cells than its recorder keeps (CellDiffRecorder's max_records):
  // `changes` is empty and the operation cannot be taken back.
  bool too_large = false;
  bool empty() const noexcept { return changes.empty(); }
  std::size_t size() const noexcept { return changes.size(); }
};

// A hash of a cell address (for maps keyed by CellCoord).
struct CellCoordHash {
  std::size_t operator()(const CellCoord& k) const noexcept;
};

// Orders cell addresses by depth, then z, y, x.
bool cell_order(const CellCoord& a, const CellCoord& b) noexcept;

// The zstd-compressed encoded form (layout above).
std::vector<std::uint8_t> encode_cell_diff(const CellDiff& diff);
// Untrusted bytes: every check above; `max_changes` bounds what is allocated.
Result<CellDiff> decode_cell_diff(std::span<const std::uint8_t> bytes, const OctreeConfig& canvas,
                                  std::uint64_t max_changes = std::uint64_t{1} << 28);

// Records an operation's changes as it makes them (the painter's and revert()'s hooks); each
// hook is called with the cell's pool index, its address and its state as the tree holds it.
// Finding a cell's record: through `slots` when given, a scratch array indexed by cell index that
// holds each cell's record number (its contents may be anything, several recorders may share
// it: a slot is trusted only when the record it names has the cell's address, and a cell
// recorded twice under two indices is merged by take()); else a hash map by address. Not
// thread-safe.
class CellDiffBudget;

class CellDiffRecorder {
 public:
  // Past `max_records` records (36 bytes each while the operation lasts) the recorder drops
  // what it has and records nothing more; take() then says too_large. With a `budget`, the
  // recorder's arrays also count against the memory it shares with other recorders (below).
  static constexpr std::size_t kDefaultMaxRecords = std::size_t{1} << 22;
  explicit CellDiffRecorder(std::uint32_t* slots = nullptr,
                            std::size_t max_records = kDefaultMaxRecords,
                            CellDiffBudget* budget = nullptr);
  ~CellDiffRecorder();
  CellDiffRecorder(CellDiffRecorder&&) noexcept;
  CellDiffRecorder& operator=(CellDiffRecorder&&) noexcept;

  // Cell c (at k) changes colour from `old_rgba` to `new_rgba` (its leaf flag as it is).
  void colour(CellIndex c, const CellCoord& k, bool leaf, std::uint32_t old_rgba,
              std::uint32_t new_rgba);
  // Leaf c (at k, colour `rgba`) gets eight children first_child.. first_child+7, each with
  // colour `child_rgba`.
  void refine(CellIndex c, const CellCoord& k, std::uint32_t rgba, std::uint32_t child_rgba,
              CellIndex first_child);
  // Internal c (at k, colour `old_rgba`) loses its eight leaf children first_child.. (colours
  // `children`) and becomes a leaf with colour `new_rgba`.
  void coarsen(CellIndex c, const CellCoord& k, std::uint32_t old_rgba,
               const std::uint32_t children[8], std::uint32_t new_rgba, CellIndex first_child);
  // The net changes so far (cells whose state differs), sorted; the recorder is emptied.
  CellDiff take();
  void clear();
  std::size_t cells() const noexcept;  // records made (changed or not)
  bool dropped() const noexcept;       // past its cap or budget: take() will say too_large

 private:
  friend class CellDiffBudget;
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// The memory several recorders hold together (a canvas's open strokes, each recording its
// change for undo), so that no mix of strokes takes it past `max_bytes`. A recorder's arrays grow
// by doubling; a growth that would pass the budget first drops the recorder holding the most
// (the growing one itself when it holds at least as much as any other; of others holding the
// same, the one made first), which then records nothing more and whose take() says too_large (its
// stroke cannot be undone), until the growth fits or the growing recorder was the one dropped.
// Which recorder is dropped depends only on the sequence of records made, not on how the work was
// split. Counts the record arrays (36 bytes a record, up to twice that with the doubling's slack),
// not a recorder's address map: recorders under a budget should have `slots`.
// Must outlive its recorders. Not thread-safe (the recorders' thread).
class CellDiffBudget {
 public:
  explicit CellDiffBudget(std::uint64_t max_bytes) : max_bytes_(max_bytes) {}
  CellDiffBudget(const CellDiffBudget&) = delete;
  CellDiffBudget& operator=(const CellDiffBudget&) = delete;

  std::uint64_t max_bytes() const noexcept { return max_bytes_; }
  std::uint64_t bytes() const noexcept { return bytes_; }      // held by its recorders now
  std::uint64_t peak_bytes() const noexcept { return peak_; }  // the most ever held
  std::uint64_t recorders_dropped() const noexcept { return dropped_; }

 private:
  friend class CellDiffRecorder;
  // `asker` wants `need` more bytes: true when they fit (after dropping others), false when
  // the asker itself must drop what it holds.
  bool grant(CellDiffRecorder::Impl* asker, std::uint64_t need);
  void release(std::uint64_t n) noexcept { bytes_ -= n; }
  void join(CellDiffRecorder::Impl* r) { members_.push_back(r); }
  void leave(CellDiffRecorder::Impl* r) noexcept;
  std::uint64_t max_bytes_;
  std::uint64_t bytes_ = 0, peak_ = 0, dropped_ = 0;
  std::vector<CellDiffRecorder::Impl*> members_;  // in the order they were made
};

}  // namespace deepcanvas::server_core
