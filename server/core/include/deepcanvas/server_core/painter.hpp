// The painter: applies strokes to an Octree with adaptive resolution and the paper's multi-step
// tree adjustment. Density model: deepcanvas/protocol/density_model.hpp; stamp geometry:
// stamp.hpp.
//
// What a stroke does
// ------------------
// Every cell the stroke touches keeps, for the stroke's duration, its pre-stroke value (a
// temporary field pool) and the stroke's strength there (another temporary pool): the maximum
// over the stroke's stamps of the per-stamp effect at the cell's centre. The cell's colour is
// always blend(pre-stroke value, strength), so overlapping stamps of one stroke never build up
// beyond the stroke's opacity (2D painting programs' stroke-level opacity), and the result does
// not depend on stamp order. Per mode (A = brush colour alpha, O = opacity, c = coverage,
// D = local stamp diameter, h = the cell's edge):
//   paint    strength q = 1 - (1 - A O c)^(h/D)  (a cell alpha); result = stroke "over" pre
//   erase    strength e = O c: the fraction of density removed (sigma' = (1 - e) sigma)
//   recolor  strength w = O c: rgb moves towards the brush colour by w, density kept
//   smudge   strength w = O c and the stamp that gave it: rgb moves by w towards the colour the
//            brush carries at that stamp. The brush loads the pre-stroke colour under its first
//            non-empty stamp (the brush colour until then) and then picks up 15% of the
//            pre-stroke colour under it per radius travelled, so colour is dragged along the
//            stroke and fades into what is there; density kept; empty cells stay empty.
//   pick_up  changes nothing; pick() reads colour and density at a point.
//
// Adaptive resolution and multi-step adjustment
// --------------------------------------------
// A stamp's target depth puts ~10 cells across its diameter (stamp.hpp). begin_stroke(),
// add_samples() and end_stroke() only turn samples into stamps (O(samples), no cell visited);
// step() does all the cell work, in bounded pieces:
//   paint    pending stamps are painted at the resolution the tree has (leaf centres), each by a
//            depth-first descent kept on an explicit stack so that it can stop after any cell;
//            every touched leaf shallower than a touching stamp's target depth (and that the
//            stroke can change: erase, recolor and smudge leave empty cells alone) is queued.
//   refine   queued cells are refined one level per step (a level may take several steps):
//            new children inherit the refined pre-stroke value (density_model refine) and
//            their strength is re-evaluated from all stamps, so the end result equals refining
//            first and painting once (paint_one_shot(), the reference; the tests compare them).
//            Refinement keeps 2:1 balance by refining coarser face neighbours first (through
//            the same path, so they get the density transform too).
//   merge    after end_stroke(), uniform children merge back (all leaves, all channels within
//            density::kMergeTolerance, density-model coarsening), deepest level first, one
//            level per step, under 2:1 balance (Octree::can_coarsen), among the cells the
//            stroke touched or created and their ancestors. Empty space always merges, so
//            erasing everything returns the tree to its roots.
// A step gives half its budget to pending paint, then refines, then paints again with what is
// left; merging starts once the stroke has ended and nothing else is pending. The result does
// not depend on how the work is cut into steps or interleaved: a cell's value is a maximum over
// stamps (new children are evaluated against every stamp already started, and a stamp started
// later reaches them through its own descent), and the set of refinements is a closure.
//
// Bounded steps: a step does at most `max_cells_per_step` work units (+ kStepWorkSlack), where
// one unit is one cell taken from the paint descent's stack (for a leaf: the stamp's effect on
// it) or one child box tested by it, one stamp started (its descent located) plus one per
// stamp-index bucket it fills (a hash-map insert: measured, these cost about as much as a cell),
// one cell created by refinement (8 per split; the split evaluates its children against the
// candidate stamps), one refine or merge queue entry examined, and 8 more per merge (the cells
// freed). Work is only started while under the cap, so a step overshoots by at most one such
// item: 8 units for a split, a merge or a cell's children, and for a stamp start its bucket
// count (at most ~130 with the default StampParams: <= 4^3 buckets at the stamp's own bucket
// level, <= 8 at each of the <= 8 coarser ones). Between steps the tree is always valid
// (balanced, check_invariants() holds) and the blocks a step changed are on the octree's dirty
// list, so a stroke's first blocks can be published after its first step however large the
// stroke.
// Determinism: the same strokes in the same order give bit-identical pools.
//
// Bounded strokes
// ---------------
// No stroke, however shaped, may take the canvas's memory: the stroke's samples must fit in a
// box of limits.max_extent_m (checked when the validated samples are made, and again here as
// a streamed stroke's samples add up: add_samples() refuses a batch past it with
// limit_exceeded and the stroke keeps what it has), and a refinement is only started while
//   the stroke has created fewer than limits.max_stroke_cells cells (else limit_exceeded,
//     "stroke created N cells: the limit is M (max_stroke_cells)"), and
//   the tree stays within its capacity: max_cells for erase strokes, max_cells less
//     capacity_reserve for the others (else out_of_memory, "canvas capacity: ...").
// Either stops the stroke: step() returns the error and the stroke is over (stroke_active()
// false). The tree is valid and keeps what the stroke painted until then (every refinement
// done had its balance refinements first; uniform children it left are merged back by later
// strokes' merge passes where they touch them).
//
// Concurrent strokes
// ------------------
// Several strokes may be open at once (the server interleaves its artists' streamed strokes
// batch by batch, so nobody waits for another's stroke to end), but only one is busy at a time:
// begin_stroke / add_samples / end_stroke give a stroke work, and step() does it to completion
// before another stroke may be given work. An open stroke that is not busy holds no reference
// to a cell except its merge queue (checked when taken: the cell may have been merged away).
// Where two open strokes touch the same cell, the later touch takes the cell over: its pre-stroke
// value is the cell as it is then (the earlier stroke's paint so far), and the earlier stroke,
// touching it again, starts over from the cell as it is (so each stroke's own opacity still holds
// within every stretch of batches, and strokes that overlap while both are open layer in the
// order of their batches): there only the stroke's stamps from the turn that took the cell back
// count, also when a later stamp refines it. A merge never frees cells another open stroke has
// touched. The result is a function of the order of the calls alone, not of the step sizes (the
// server steps a turn in small and large steps, a replay in large ones; the server records the
// order: StrokeEvent); strokes far enough apart to share no cells give the same canvas in any
// interleaving as one after another (tests/painting/painter_test.cpp).
//
// Threading: a Painter and its Octree belong to one thread (the canvas's stroke thread).
// Untrusted input: the painter takes protocol::ValidatedStroke / ValidatedBrush /
// ValidatedSamples (stroke.hpp), made at the boundary with this canvas's rules
// (stroke_rules()), and does not check them again. The overloads that take plain values are for
// strokes built in code (tests, benchmarks, replays): they make the validated types with
// stroke_rules() first, and a stroke that fails them changes nothing.
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <span>
#include <vector>

#include "deepcanvas/base/result.hpp"
#include "deepcanvas/protocol/stroke.hpp"
#include "deepcanvas/server_core/cell_diff.hpp"
#include "deepcanvas/server_core/cell_paste.hpp"
#include "deepcanvas/server_core/octree.hpp"
#include "deepcanvas/server_core/stamp.hpp"

namespace deepcanvas::server_core {

// The most a step may exceed max_cells_per_step by, in work units, with the default StampParams
// (a stamp started just under the cap; see the top comment).
inline constexpr std::uint64_t kStepWorkSlack = 136;

struct PainterConfig {
  std::uint64_t max_cells_per_step = 1u << 16;  // work units per step (see above); >= 8
  StampParams stamps;
  // The limits of stroke_rules(), for the overloads that take plain strokes. max_extent_m and
  // max_stroke_cells also bound the validated calls (see "Bounded strokes" above).
  protocol::StrokeLimits limits{100000, 1000.0, 1e-7};
  // The fraction of the octree's capacity (OctreeConfig::max_cells) kept for erase strokes:
  // paint, recolor and smudge strokes stop growing the tree at max_cells x (1 - reserve), so a
  // full canvas can always be erased (and erasing merges cells back). In [0, 0.5].
  double capacity_reserve = 0.05;
  // Shortcuts that skip evaluations whose outcome is already known: a stamp skips the coverage
  // of a leaf that holds at least the most the stamp gives any point (full coverage at its
  // narrowest end), and the logarithm where a cheap upper bound of its strength there is below
  // the leaf's; a cell wholly within the stamp's reach skips its children's box tests, and one
  // wholly within its hard core their coverage. The result is identical either way (tested);
  // false only for with/without comparisons.
  bool exact_shortcuts = true;
  // Record every stroke's changes, cell by cell (a CellDiff; take_stroke_diff()), so that it can
  // be undone (revert()). Costs 36 bytes per changed cell while the stroke is open.
  bool record_diffs = false;
  // The memory the open strokes' recordings hold together (CellDiffBudget): past it the largest
  // recording is dropped and its stroke's diff says too_large (it cannot be undone).
  std::uint64_t max_recording_bytes = 64u << 20;
};

// What Painter::revert() did.
struct RevertStats {
  std::uint64_t restored = 0;  // cells set back to their state before the operation
  std::uint64_t kept = 0;      // cells left as they are: painted over since, or held
  std::uint64_t cells_changed = 0;  // cells created, freed or recoloured by the revert
};

struct PasteStats {
  std::uint64_t cells = 0;          // cells in the paste
  std::uint64_t cells_changed = 0;  // cells created, freed or recoloured
};

struct PickResult {
  float rgb[3] = {0, 0, 0};
  float alpha = 0;  // stored alpha: opacity across one cell edge at `depth`
  double cell_edge_m = 0;
  double sigma_per_m = 0;  // extinction per metre (infinite when alpha is 1)
  int depth = 0;
  CellIndex cell = kNoCell;
};

struct StrokeStats {
  std::uint64_t stamps = 0;
  std::uint64_t samples = 0;
  std::uint64_t cells_created = 0;
  std::uint64_t cells_freed = 0;
  std::uint64_t cells_recoloured = 0;  // colour writes that changed a value
  std::uint64_t steps = 0;             // step() calls that did work
  std::uint64_t work = 0;              // work units, all steps (see the top comment)
  std::uint64_t max_step_work = 0;     // the largest step's work units
  std::uint64_t cells_changed() const { return cells_created + cells_freed + cells_recoloured; }
};

class Painter {
 public:
  // The octree must outlive the painter. Allocates the temporary pools.
  static Result<std::unique_ptr<Painter>> create(Octree& tree, const PainterConfig& config = {});
  ~Painter();
  Painter(const Painter&) = delete;
  Painter& operator=(const Painter&) = delete;

  // The rules a stroke for this painter is validated with: the canvas bounds of the tree and
  // PainterConfig::limits.
  protocol::StrokeRules stroke_rules() const noexcept;

  // ---- step-wise API (the server's stroke thread) ----
  // Several strokes may be open at once (see "Concurrent strokes" above); at most one of them
  // is busy (has painting or merging left to do). A call that gives a stroke new work (begin,
  // samples, end) is refused while another stroke is busy: step() until it is not.
  //
  // Starts stroke `stroke_id` with `brush` and its first samples (may be empty). refused if a
  // stroke with that id is open or another stroke is busy. The samples become stamps; step()
  // paints them (the first step already paints up to its budget). limit_exceeded when the
  // stroke needs more stamps than StampParams allow.
  Result<void> begin_stroke(const protocol::ValidatedBrush& brush, std::uint64_t stroke_id,
                            const protocol::ValidatedSamples& samples);
  // More samples of open stroke `stroke_id` (segments join its previous sample); step() paints
  // them. limit_exceeded (nothing changed, the stroke stays open) when they would take the
  // stroke's box past limits.max_extent_m or its stamps past StampParams' limit.
  Result<void> add_samples(std::uint64_t stroke_id, const protocol::ValidatedSamples& samples);
  // No more samples for `stroke_id`: the remaining steps finish refinement, then merge back.
  Result<void> end_stroke(std::uint64_t stroke_id);
  // The same for the only open stroke (refused when none or several are open).
  Result<void> add_samples(const protocol::ValidatedSamples& samples);
  Result<void> end_stroke();
  // One bounded step of the busy stroke's work. true: more work is pending (call again); false:
  // nothing to do now (no stroke is busy: each open stroke waits for samples or its end).
  Result<bool> step();
  // The same with a budget of `max_work` units (>= 8) instead of max_cells_per_step: the result
  // does not depend on how the work is cut into steps, so a caller may make some steps smaller
  // (the server's first step of a stroke, so that its first epoch is small and leaves at once).
  // An error stops the busy stroke (it is closed; see "Bounded strokes").
  Result<bool> step(std::uint64_t max_work);
  bool stroke_active() const noexcept;  // some stroke is open
  bool stroke_open(std::uint64_t stroke_id) const noexcept;
  std::size_t open_strokes() const noexcept;
  // The stroke step() works on, if any.
  std::optional<std::uint64_t> busy_stroke() const noexcept;
  // The busy stroke has ended and all of its paint is in the tree (every stamp painted, every
  // refinement done): what remains is merging uniform children back, which changes how cells are
  // stored, not what they show (within density::kMergeTolerance). False without a busy stroke.
  bool stroke_painted() const noexcept;

  // ---- convenience ----
  // begin + add + end + step until done. A pick_up stroke picks at its first sample.
  Result<StrokeStats> apply_stroke(const protocol::ValidatedStroke& stroke);
  // The reference: refine everything the stroke touches to its target depth first, then paint
  // once, then merge back. Same final canvas as apply_stroke (tested), without the bounded steps.
  Result<StrokeStats> paint_one_shot(const protocol::ValidatedStroke& stroke);

  // ---- strokes built in code ----
  // The calls above for plain values: invalid_argument or limit_exceeded (nothing changed) when
  // they fail stroke_rules(), otherwise the same as the validated call.
  Result<void> begin_stroke(const protocol::Brush& brush, std::uint64_t stroke_id,
                            std::span<const protocol::StrokeSample> samples);
  Result<void> add_samples(std::span<const protocol::StrokeSample> samples);
  Result<void> add_samples(std::uint64_t stroke_id,
                           std::span<const protocol::StrokeSample> samples);
  Result<StrokeStats> apply_stroke(const protocol::Stroke& stroke);
  Result<StrokeStats> paint_one_shot(const protocol::Stroke& stroke);

  // Colour and density at a point (the leaf containing it). Changes nothing.
  Result<PickResult> pick(const Vec3d& p) const;
  // The result of the last pick_up stroke.
  const std::optional<PickResult>& last_pick() const noexcept;
  // ---- undo (PainterConfig::record_diffs) ----
  // The changes stroke `stroke_id` made, once it has finished or was stopped (then what it
  // painted until it stopped); each stroke's diff is given once. nullopt when none is kept.
  std::optional<CellDiff> take_stroke_diff(std::uint64_t stroke_id);
  // PainterConfig::record_diffs for the strokes opened from now on.
  void set_record_diffs(bool on) noexcept;
  // The open strokes' recordings against PainterConfig::max_recording_bytes.
  const CellDiffBudget& recording_budget() const noexcept;
  const OctreeConfig& octree_config() const noexcept;
  // Takes back the changes of `diff` (a stroke's, or a revert's own result), exactly, where the
  // canvas still holds what they left: cell by cell at the finest resolution the diff has, a
  // cell whose state is still diff.after gets diff.before (a cell the operation created gets
  // the value it had before, refined down to its depth, density_model refine). Cells painted
  // over since (another state), or touched by a stroke still open, keep what they hold; cells
  // that were painted over more finely since are restored leaf by leaf where the finer leaves
  // still hold what the operation left there (refined). Then the cells the operation created
  // are merged back, deepest first, where all eight were restored and 2:1 balance allows, and
  // the cells it merged away are refined again where their parent was restored. Where nothing
  // was painted over this gives exactly the canvas before the operation (canvas_hash), and
  // reverting the returned diff (what this call changed) gives exactly the canvas before it.
  // Refused while a stroke is busy (step() until it is not). The changed blocks are dirty.
  Result<CellDiff> revert(const CellDiff& diff, RevertStats* stats = nullptr);
  // ---- import ----
  // Sets the paste's cells (cell_paste.hpp: each becomes a leaf of its value, replacing finer
  // paint inside it; uniform siblings merged after, where balance allows) and returns what it
  // changed (for undo: revert() of it takes the import back; too_large past the recorder's
  // cap). Cells of strokes still open are overwritten (their strokes paint on over the new
  // value). The paste must be normalised (decode_cell_paste / normalise_cell_paste). Refused
  // while a stroke is busy; out_of_memory, with nothing changed, where the canvas has no room.
  // The changed blocks are dirty.
  Result<CellDiff> paste(const CellPaste& paste, PasteStats* stats = nullptr);

  // Stats of the stroke the last call addressed (the busy one for step()), also once it has
  // finished or failed.
  const StrokeStats& stroke_stats() const noexcept;

 private:
  struct Impl;     // one open stroke's state (painter_impl.hpp)
  struct Shared;   // the canvas's side: tree, temporary pools, open strokes
  explicit Painter(std::unique_ptr<Shared> shared);
  std::unique_ptr<Shared> shared_;
};

}  // namespace deepcanvas::server_core
