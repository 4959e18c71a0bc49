// StreamingReplica: upload thread, CPU mirror and GPU lock (see streaming_replica.hpp).
#include "deepcanvas/client_gpu/streaming_replica.hpp"
#include "deepcanvas/base/thread_name.hpp"

#include <algorithm>
#include <cstring>
#include <iterator>
#include <random>

#include "deepcanvas/client_gpu/errors.hpp"
#include "pool_layout.h"
#include "streaming_replica_content.hpp"

namespace deepcanvas::client_gpu {
namespace {

namespace L = pool_layout;
using Clock = std::chrono::steady_clock;

double ms_since(SteadyTime t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

constexpr auto kShrinkIdleAfter = std::chrono::milliseconds(500);
constexpr auto kShrinkAtLatest = std::chrono::seconds(5);

}  // namespace

void GpuLock::lock() {
  std::unique_lock l(mutex_);
  const std::uint64_t ticket = next_++;
  cv_.wait(l, [&] { return serving_ == ticket; });
}

bool GpuLock::try_lock() {
  std::lock_guard l(mutex_);
  if (serving_ != next_) return false;  // held, or others are waiting their turn
  ++next_;
  return true;
}

void GpuLock::unlock() {
  {
    std::lock_guard l(mutex_);
    ++serving_;
  }
  cv_.notify_all();
}

StreamingReplica::StreamingReplica() = default;

Result<std::unique_ptr<StreamingReplica>> StreamingReplica::create(const Context& ctx,
                                                                   const GpuReplicaConfig& cfg,
                                                                   const UploadBudget& budget,
                                                                   const UploadChaos& chaos) {
  auto rep = GpuReplica::create(ctx, cfg);
  if (!rep) return std::move(rep).error();
  std::unique_ptr<StreamingReplica> s(new StreamingReplica());
  s->replica_ = std::move(*rep);
  s->width_log2_ = cfg.width_log2;
  s->policy_ = UploadBatchPolicy(budget, Clock::now());
  s->chaos_ = chaos;
  s->roots_per_axis_ = cfg.roots_per_axis;
  s->edge_m_ = cfg.edge_m;
  s->content_ = std::make_unique<detail::ContentTracker>();
  {
    // Address space only: see m_first_child_.
    const std::size_t cells = std::size_t{1} << L::kMaxCellsLog2;
    s->m_first_child_ = client_core::PoolArray<std::uint32_t>(cells);
    s->m_colour_ = client_core::PoolArray<std::uint32_t>(cells);
    s->m_group_parent_ = client_core::PoolArray<std::uint32_t>(cells / 8);
    s->m_depth_flags_ = client_core::PoolArray<std::uint8_t>(cells / 8);
    s->m_links_ = client_core::PoolArray<std::uint32_t>(cells / 8 * L::kFaceCount);
    try {
      s->m_first_child_.resize(cells);
      s->m_colour_.resize(cells);
      s->m_group_parent_.resize(cells / 8);
      s->m_depth_flags_.resize(cells / 8);
      s->m_links_.resize(cells / 8 * L::kFaceCount);
    } catch (const std::bad_alloc&) {
      return gpu_error(GpuErrc::out_of_memory,
                       "streaming replica: no address space for the CPU mirror (3.1 GiB)");
    }
    s->m_row_prepared_.assign(cells >> cfg.width_log2, 0);
  }
  s->thread_ = std::thread([p = s.get()] {
    base::set_thread_name("dc-upload");
    p->upload_thread();
  });
  return s;
}

StreamingReplica::~StreamingReplica() {
  {
    std::lock_guard l(mutex_);
    stop_ = true;
  }
  cv_.notify_all();
  if (thread_.joinable()) thread_.join();
}

void StreamingReplica::push(EpochUpload upload) {
  {
    std::lock_guard l(mutex_);
    if (pushed_any_ && upload.epoch < last_pushed_) return;
    pushed_any_ = true;
    last_pushed_ = upload.epoch;
    queue_.push_back(std::move(upload));
  }
  cv_.notify_all();
}

client_core::PoolView StreamingReplica::mirror_view() const noexcept {
  client_core::PoolView v;
  // The vectors run past m_cells_ (room to grow, already holding the never-used values).
  const std::size_t n = m_cells_;
  v.first_child = std::span<const std::uint32_t>(m_first_child_).first(n);
  v.colour = std::span<const std::uint32_t>(m_colour_).first(n);
  v.group_parent = std::span<const std::uint32_t>(m_group_parent_).first(n / 8);
  v.group_depth_flags = std::span<const std::uint8_t>(m_depth_flags_).first(n / 8);
  v.group_links = std::span<const std::uint32_t>(m_links_).first(n / 8 * 6);
  v.roots_per_axis = roots_per_axis_;
  v.edge_m = edge_m_;
  v.filtered_interiors = true;  // the server's values: 0 exactly over empty subtrees (4.4)
  return v;
}

Result<void> StreamingReplica::with_gpu(
    const std::function<Result<void>(const ResidentState&)>& fn) {
  std::lock_guard l(gpu_lock_);
  const ResidentState st{m_any_, m_epoch_, m_partial_, mirror_view(), *replica_, m_content_};
  return fn(st);
}

namespace {
std::uint64_t cells_of(const std::vector<EpochUpload>& batch) {
  std::uint64_t cells = 0;
  for (const EpochUpload& e : batch) cells = std::max(cells, e.cell_count);
  return cells;
}
}  // namespace

double StreamingReplica::prepare_mirror_rows(std::span<const std::uint32_t> rows) {
  const auto t = Clock::now();
  const std::uint64_t w = std::uint64_t{1} << width_log2_;
  for (const std::uint32_t r : rows) {
    if (r >= m_row_prepared_.size() || m_row_prepared_[r]) continue;
    m_row_prepared_[r] = 1;
    const std::uint64_t c0 = std::uint64_t{r} * w;
    // colour's never-used value is zero, which the row holds already.
    std::fill_n(&m_first_child_[c0], w, L::kNoCell);
    std::fill_n(&m_group_parent_[c0 / 8], w / 8, L::kNoCell);
    std::fill_n(&m_depth_flags_[c0 / 8], w / 8, static_cast<std::uint8_t>(L::kGroupFreeFlag));
    std::fill_n(&m_links_[c0 / 8 * L::kFaceCount], w / 8 * L::kFaceCount, L::kNoCell);
  }
  return ms_since(t);
}

void StreamingReplica::apply_to_mirror(const std::vector<EpochUpload>& batch) {
  if (batch.empty()) return;
  const std::uint64_t w = std::uint64_t{1} << batch.front().width_log2;
  const std::uint64_t cells = std::min<std::uint64_t>(cells_of(batch), m_first_child_.size());
  std::uint32_t max_row = 0;
  for (const EpochUpload& e : batch)
    if (!e.rows.empty()) max_row = std::max(max_row, e.rows.back());
  m_cells_ = std::max(m_cells_, cells);
  // The last epoch carrying a row wins: walk the epochs from the last and copy each row once
  // (a merged batch of a stroke's painter steps carries the same rows many times over).
  const std::uint64_t have = m_cells_;
  std::vector<std::uint8_t> done(std::size_t{max_row} + 1, 0);
  for (auto it = batch.rbegin(); it != batch.rend(); ++it) {
    const EpochUpload& e = *it;
    for (std::size_t i = 0; i < e.rows.size(); ++i) {
      if (done[e.rows[i]]) continue;
      done[e.rows[i]] = 1;
      const std::uint64_t c0 = std::uint64_t{e.rows[i]} * w;
      if (c0 >= have) continue;
      const std::uint64_t n = std::min(w, have - c0);
      std::memcpy(&m_first_child_[c0], &e.first_child[i * w], n * 4);
      std::memcpy(&m_colour_[c0], &e.colour[i * w], n * 4);
      std::memcpy(&m_group_parent_[c0 / 8], &e.group_parent[i * w / 8], n / 8 * 4);
      std::memcpy(&m_depth_flags_[c0 / 8], &e.depth_flags[i * w / 8], n / 8);
    }
  }
}

std::optional<client_core::DAabb> StreamingReplica::exact_content_bounds() const {
  const client_core::PoolView v = mirror_view();
  auto b = client_core::painted_bounds(v);
  if (b) return *b;
  // Pools painted_bounds refuses (a cycle, a bad index): the whole canvas is conservative.
  const double h = v.edge_m * 0.5;
  return client_core::DAabb{{-h, -h, -h}, {h, h, h}};
}

void StreamingReplica::set_exact_content() {
  const auto t = Clock::now();
  m_content_ = exact_content_bounds();
  content_loose_ = false;
  content_exact_at_ = Clock::now();
  ++content_exact_;
  max_content_exact_ms_ = std::max(max_content_exact_ms_, ms_since(t));
}

void StreamingReplica::maybe_shrink_content(bool queue_empty) {
  if (!content_loose_ || content_broken_ || !m_any_) return;
  const auto since = Clock::now() - content_exact_at_;
  if (!(queue_empty && since >= kShrinkIdleAfter) && since < kShrinkAtLatest) return;
  // painted_bounds on the mirror outside the lock (only this thread writes the mirror), then
  // swapped in under it: the state is still the resident epoch's.
  const auto t = Clock::now();
  auto box = exact_content_bounds();
  {
    std::lock_guard l(gpu_lock_);
    m_content_ = box;
  }
  content_loose_ = false;
  content_exact_at_ = Clock::now();
  ++content_exact_;
  max_content_exact_ms_ = std::max(max_content_exact_ms_, ms_since(t));
  std::lock_guard l(mutex_);
  stats_.content_exact = content_exact_;
  stats_.max_content_exact_ms = max_content_exact_ms_;
}

namespace {

// The rows and link groups of `epochs`, sorted and unique; false when one has another width.
bool merged_rows(std::span<const EpochUpload> epochs, std::uint32_t width_log2,
                 std::vector<std::uint32_t>& rows, std::vector<std::uint32_t>& groups) {
  rows.clear();
  groups.clear();
  for (const EpochUpload& e : epochs) {
    if (e.width_log2 != width_log2) return false;
    rows.insert(rows.end(), e.rows.begin(), e.rows.end());
    groups.insert(groups.end(), e.link_groups.begin(), e.link_groups.end());
  }
  std::sort(rows.begin(), rows.end());
  rows.erase(std::unique(rows.begin(), rows.end()), rows.end());
  std::sort(groups.begin(), groups.end());
  groups.erase(std::unique(groups.begin(), groups.end()), groups.end());
  return true;
}

// UploadChaos: the rows in random order and random chunks, each its own submission, with pauses
// between them, still under the GPU lock `l` (no band can observe the partial state) unless
// chaos.break_atomicity (the negative control) releases it between chunks.
Result<void> upload_in_random_chunks(GpuReplica& replica, const client_core::PoolView& view,
                                     std::vector<std::uint32_t>& rows, const UploadChaos& chaos,
                                     std::mt19937_64& rng, std::unique_lock<GpuLock>& l) {
  std::shuffle(rows.begin(), rows.end(), rng);
  std::size_t i = 0;
  while (i < rows.size()) {
    const std::size_t n = 1 + rng() % std::min<std::size_t>(rows.size() - i, 8);
    if (auto v = replica.upload_row_list(view, std::span<const std::uint32_t>(rows.data() + i, n));
        !v)
      return v;
    i += n;
    if (chaos.break_atomicity) {
      l.unlock();
      std::this_thread::sleep_for(std::chrono::microseconds(2000));
      l.lock();
    } else {
      std::this_thread::sleep_for(std::chrono::microseconds(rng() % 300));
    }
  }
  return {};
}

}  // namespace

// Each of `rows` (sorted, unique, each carried by an epoch of `batch`) as the last epoch of
// `batch` carrying it holds it: the row the mirror will hold after the batch (rows past the
// high-water mark hold the never-used values in both).
static std::vector<GpuReplica::RowSource> row_sources(const std::vector<EpochUpload>& batch,
                                                      std::span<const std::uint32_t> rows,
                                                      std::uint32_t width_log2) {
  const std::size_t w = std::size_t{1} << width_log2;
  std::vector<GpuReplica::RowSource> out(rows.size());
  std::vector<std::uint8_t> done(rows.size(), 0);
  for (auto it = batch.rbegin(); it != batch.rend(); ++it) {
    const EpochUpload& e = *it;
    for (std::size_t i = 0; i < e.rows.size(); ++i) {
      const auto at = std::lower_bound(rows.begin(), rows.end(), e.rows[i]);
      const std::size_t k = static_cast<std::size_t>(at - rows.begin());
      if (at == rows.end() || *at != e.rows[i] || done[k]) continue;
      done[k] = 1;
      out[k] = {e.rows[i], std::span(e.first_child).subspan(i * w, w),
                std::span(e.colour).subspan(i * w, w),
                std::span(e.group_parent).subspan(i * w / 8, w / 8),
                std::span(e.depth_flags).subspan(i * w / 8, w / 8)};
    }
  }
  return out;
}

Result<void> StreamingReplica::apply_batch(std::vector<EpochUpload>& batch,
                                           std::uint32_t max_epochs, ResidentBatch& out) {
  std::vector<std::uint32_t> rows, groups;
  if (!merged_rows(batch, width_log2_, rows, groups))
    return gpu_error(GpuErrc::bad_argument, "streaming replica: epoch of another width");
  std::mt19937_64 rng(chaos_.seed ^ batch.front().epoch);
  // The content box after the batch, from its rows over the mirror before it: outside the lock
  // (only this thread writes the mirror and the box).
  ++batch_number_;
  const bool skip_content =
      chaos_.skip_content_growth_batch != 0 && batch_number_ == chaos_.skip_content_growth_batch;
  // The rows this batch writes first hold the never-used values before the content step reads
  // them as the state before the batch. Outside the lock (only this thread writes the mirror;
  // bands never read such rows): on a VM, first touching the pools of a million cells took 40
  // to 50 ms, which under the lock delayed a headset frame by as much.
  out.mirror_prepare_ms = prepare_mirror_rows(rows);
  const auto t_content = Clock::now();
  detail::ContentStep content;
  if (m_any_ && !skip_content)
    content = content_->step(mirror_view(), m_content_, batch, rows, width_log2_);
  out.content_ms = ms_since(t_content);
  out.changed_cells = content.changed_cells;

  // The rows' bytes go into the staging buffer here too, from the batch (the mirror gets them
  // only under the lock): filling it for demo.apa's largest stroke (9 MB) took 7 to 56 ms on a
  // VM. Not with the chaos of split submissions, which uploads in pieces from the mirror.
  const bool split = chaos_.seed && chaos_.split_submissions && rows.size() > 1;
  const auto t_stage = Clock::now();
  std::optional<GpuReplica::StagedRows> staged;
  if (!split) {
    auto s = replica_->stage_rows(row_sources(batch, rows, width_log2_));
    if (!s) return std::move(s).error();
    staged = std::move(*s);
  }
  out.stage_ms = ms_since(t_stage);
  const auto t_lock = Clock::now();
  std::unique_lock l(gpu_lock_, std::try_to_lock);
  const bool waited = !l.owns_lock();
  if (waited) l.lock();
  const auto t0 = Clock::now();
  out.lock_wait_ms = ms_since(t_lock);
  // Late joiners: epochs committed while this batch waited for a band to end go with it (they
  // would otherwise wait for the next band after it). Only after a wait, so a batch placed in a
  // gap between frames does not outgrow its estimate.
  std::vector<EpochUpload> late;
  if (waited) {
    UploadBatchPolicy::LateRoom room{max_epochs, replica_->capacity_cells(),
                                     m_first_child_.size(),
                                     0};
    std::lock_guard q(mutex_);
    while (!queue_.empty() &&
           UploadBatchPolicy::may_join_late(queue_.front(), batch.size() + late.size(), room)) {
      room.late_rows += queue_.front().rows.size();
      late.push_back(std::move(queue_.front()));
      queue_.pop_front();
    }
  }
  apply_to_mirror(batch);
  out.mirror_ms = ms_since(t0);
  // The box goes with the mirror, in the same critical section.
  if (skip_content) {
    content_broken_ = true;  // the negative control: the box misses what this batch painted
  } else {
    take_content_step(content, !m_any_, out);
  }
  std::vector<std::uint32_t> late_rows;
  if (!late.empty()) {
    if (auto v = apply_late_joiners(batch, late, rows, groups, late_rows, out); !v) return v;
  }
  const client_core::PoolView view = mirror_view();
  // Growth: what the batch needs at once (completing a growth under way if the textures are
  // too small: the stall the incremental growth avoids, when a stream outruns it); ahead of
  // need, past half full, an incremental growth whose steps run in gaps (growth_step_in_gap).
  const auto t_grow = Clock::now();
  const std::uint64_t before = replica_->generation();
  if (auto v = replica_->reserve(view.cell_count()); !v) return v;
  out.grew = replica_->generation() != before;
  if (!replica_->growing() &&
      UploadBatchPolicy::begin_growth_ahead(view.cell_count(), replica_->capacity_cells(),
                                            replica_->max_growth_cells())) {
    // At the device or 2^28 limit this fails; reserve() reports that when the cells are needed.
    (void)replica_->begin_growth(replica_->capacity_cells() + 1);
  }
  out.grow_ms = ms_since(t_grow);
  const auto t_up = Clock::now();
  if (split) {
    if (auto v = upload_in_random_chunks(*replica_, view, rows, chaos_, rng, l); !v) return v;
  } else {
    if (auto v = replica_->upload_staged(view, *staged); !v) return v;
    // Late joiners' rows, from the mirror (now after them), over the batch's.
    if (!late_rows.empty()) {
      if (auto v = replica_->upload_row_list(view, late_rows); !v) return v;
    }
  }
  out.upload_ms = ms_since(t_up);
  const auto t_links = Clock::now();
  if (!groups.empty()) {
    if (auto v = replica_->compute_links(view, groups); !v) return v;
  }
  out.links_ms = ms_since(t_links);
  out.rows = rows.size();
  out.link_groups = groups.size();
  for (const EpochUpload& e : batch) out.commits.emplace_back(e.epoch, e.committed_at);
  m_any_ = true;
  m_epoch_ = batch.back().epoch;
  m_partial_ = batch.back().partial;
  out.partial = m_partial_;
  out.first_epoch = batch.front().epoch;
  out.last_epoch = batch.back().epoch;
  out.committed_at = batch.front().committed_at;
  out.resident_at = Clock::now();
  out.gpu_lock_ms = ms_since(t0);
  return {};
}

Result<void> StreamingReplica::apply_late_joiners(std::vector<EpochUpload>& batch,
                                                  std::vector<EpochUpload>& late,
                                                  std::vector<std::uint32_t>& rows,
                                                  std::vector<std::uint32_t>& groups,
                                                  std::vector<std::uint32_t>& late_rows,
                                                  ResidentBatch& out) {
  // The late epochs as a batch of their own over the mirror after `batch` (content box step,
  // then the mirror); their rows are uploaded after the batch's, their links with its links.
  std::vector<std::uint32_t> late_groups;
  if (!merged_rows(late, width_log2_, late_rows, late_groups))
    return gpu_error(GpuErrc::bad_argument, "streaming replica: epoch of another width");
  const auto t_late = Clock::now();
  // Their new rows prepared here, under the lock: at most kMaxLateRows of them.
  out.mirror_prepare_ms += prepare_mirror_rows(late_rows);
  const detail::ContentStep late_content =
      content_->step(mirror_view(), m_content_, late, late_rows, width_log2_);
  out.content_ms += ms_since(t_late);
  out.changed_cells += late_content.changed_cells;
  const auto t_mirror = Clock::now();
  apply_to_mirror(late);
  out.mirror_ms += ms_since(t_mirror);
  take_content_step(late_content, false, out);
  for (EpochUpload& e : late) {
    out.bytes += e.bytes();
    batch.push_back(std::move(e));
  }
  out.late_epochs = late.size();
  // Both lists are sorted and unique: their union is what merged_rows over the whole batch
  // would give.
  const auto unite = [](std::vector<std::uint32_t>& into, const std::vector<std::uint32_t>& add) {
    std::vector<std::uint32_t> all;
    all.reserve(into.size() + add.size());
    std::set_union(into.begin(), into.end(), add.begin(), add.end(), std::back_inserter(all));
    into.swap(all);
  };
  unite(rows, late_rows);
  unite(groups, late_groups);
  return {};
}

void StreamingReplica::take_content_step(const detail::ContentStep& step, bool exact,
                                         ResidentBatch& out) {
  if (exact || step.fallback) {
    // No box to grow yet, or a state that is not a tree: exact, under the lock.
    const auto t_exact = Clock::now();
    set_exact_content();
    if (step.fallback) ++content_fallbacks_;
    out.content_exact_ms += ms_since(t_exact);
  } else {
    m_content_ = step.box;
    content_loose_ = content_loose_ || step.loose;
  }
}

StreamingReplica::GapWait StreamingReplica::wait_for_gap(std::unique_lock<std::mutex>& l,
                                                         SteadyTime since, double estimate_ms) {
  GapWait out;
  if (!frames_.gaps_apply()) return out;
  out.scheduled = true;
  const auto t_wait = Clock::now();
  const GapWindow window = UploadBatchPolicy::gap_window(since, frames_.gap_wait_ms);
  for (;;) {
    if (stop_) {
      out.stop = true;
      return out;
    }
    if (!frames_.gaps_apply()) break;
    const GapDecision d = UploadBatchPolicy::decide_gap(frames_, Clock::now(), window, estimate_ms);
    if (d.action == GapDecision::Action::go) break;
    if (d.action == GapDecision::Action::go_mid_frame) {
      out.mid_frame = true;
      break;
    }
    cv_.wait_until(l, d.wait_until);
  }
  out.waited_ms = ms_since(t_wait);
  return out;
}

void StreamingReplica::growth_step_in_gap(bool urgent) {
  if (!urgent) {
    std::unique_lock l(mutex_);
    if (wait_for_gap(l, Clock::now(), UploadBatchPolicy::kGrowthStepTargetMs).stop) return;
  }
  Result<bool> r = true;
  SteadyTime t;
  {
    std::lock_guard g(gpu_lock_);
    t = Clock::now();  // the step itself, not the wait for the lock
    r = replica_->growth_step(chaos_.seed && chaos_.growth_rows_per_step
                                  ? chaos_.growth_rows_per_step
                                  : policy_.growth_rows_per_step());
  }
  const double ms = ms_since(t);
  if (r) policy_.growth_step_took(ms, *r);
  std::lock_guard l(mutex_);
  if (!r) {
    status_ = std::move(r).error();
    return;
  }
  ++stats_.growth_steps;
  stats_.max_growth_step_ms = std::max(stats_.max_growth_step_ms, ms);
  if (*r) ++stats_.growths;
}

void StreamingReplica::make_room(std::vector<EpochUpload>& batch, std::uint32_t& max_epochs,
                                 std::uint64_t& bytes) {
  const auto fits = [&](const EpochUpload& e) {
    return UploadBatchPolicy::fits(e, replica_->capacity_cells());
  };
  // The first epoch needs taller textures: complete the growth under way (or one begun now) in
  // steps first, each its own turn under the lock; past kGrowthRoundsBeforeBatch growths, or
  // when a growth cannot begin (the device's or the 2^28 limit), apply_batch's reserve() grows
  // at once or reports the error.
  for (int round = 0; round < UploadBatchPolicy::kGrowthRoundsBeforeBatch && !fits(batch.front());
       ++round) {
    if (!replica_->growing()) {
      std::lock_guard g(gpu_lock_);
      if (!replica_->begin_growth(batch.front().cell_count)) break;
    }
    while (replica_->growing() && status()) growth_step_in_gap(true);
  }
  // Epochs past what the textures hold go back to the queue for the next batch (which then
  // grows in steps as above), and none may join this batch late.
  const std::size_t fit = UploadBatchPolicy::epochs_that_fit(batch, replica_->capacity_cells());
  if (fit == batch.size()) return;
  std::lock_guard l(mutex_);
  for (std::size_t i = batch.size(); i-- > fit;) {
    bytes -= batch[i].bytes();
    queue_.push_front(std::move(batch[i]));
  }
  batch.resize(fit);
  max_epochs = static_cast<std::uint32_t>(fit);
}

StreamingReplica::Work StreamingReplica::wait_for_work() {
  for (;;) {
    std::unique_lock l(mutex_);
    // While the content box is loose, wake up to shrink it once the queue stays empty.
    while (!stop_ && queue_.empty()) {
      if (replica_->growing() && status_) break;  // growth steps while idle
      if (content_loose_ && !content_broken_ && status_) {
        if (Clock::now() - content_exact_at_ >= kShrinkIdleAfter) {
          l.unlock();
          maybe_shrink_content(true);
          l.lock();
          continue;
        }
        cv_.wait_until(l, content_exact_at_ + kShrinkIdleAfter);
      } else {
        cv_.wait(l);
      }
    }
    if (stop_) return Work::stop;
    if (!status_) {  // after an error, drop what arrives
      queue_.clear();
      continue;
    }
    return queue_.empty() ? Work::growth_step : Work::batch;
  }
}

bool StreamingReplica::wait_for_budget() {
  while (const auto wait = policy_.byte_budget_wait(Clock::now())) {
    std::unique_lock l(mutex_);
    if (cv_.wait_for(l, *wait, [&] { return stop_; })) return false;
  }
  std::unique_lock l(mutex_);
  if (policy_.frame_budget_spent(frames_)) {
    const std::uint64_t f = frames_.frames_started;
    cv_.wait_for(l, std::chrono::seconds(1), [&] {
      return stop_ || frames_.frames_started != f || frames_.attached_loops == 0;
    });
    if (stop_) return false;
    policy_.frame_budget_restart(frames_);
  }
  return true;
}

void StreamingReplica::record_batch(const Result<void>& r, const ResidentBatch& rb,
                                    std::size_t epochs, std::uint64_t bytes) {
  {
    std::lock_guard l(mutex_);
    if (!r) {
      status_ = r.error();
    } else {
      any_resident_ = true;
      if (!rb.partial) {
        whole_resident_ = true;
        resident_epoch_ = rb.last_epoch;
      }
      stats_.epochs += epochs;
      stats_.late_epochs += rb.late_epochs;
      ++stats_.batches;
      stats_.bytes += bytes;
      stats_.max_batch_lock_ms = std::max(stats_.max_batch_lock_ms, rb.gpu_lock_ms);
      if (rb.grew) {
        ++stats_.growths;
        stats_.max_growth_ms = std::max(stats_.max_growth_ms, rb.gpu_lock_ms);
      }
      stats_.content_exact = content_exact_;
      stats_.content_fallbacks = content_fallbacks_;
      stats_.max_content_exact_ms = max_content_exact_ms_;
      log_.push_back(rb);
      if (log_.size() > (1u << 20)) log_.erase(log_.begin(), log_.begin() + (1u << 19));
    }
  }
  cv_.notify_all();
}

void StreamingReplica::after_batch() {
  if (replica_->growing()) {
    // One step after each batch; when urgent (past 3/4 full, or less than a quarter of a growth
    // left: UploadBatchPolicy::growth_urgent), the rest now (each step its own turn under the
    // FIFO lock, so bands go between), before a batch has to grow at once.
    const bool urgent = UploadBatchPolicy::growth_urgent(m_cells_, replica_->capacity_cells(),
                                                         replica_->max_growth_cells());
    do {
      growth_step_in_gap(urgent);
    } while (urgent && replica_->growing() && status());
  }
  bool queue_empty = false;
  {
    std::lock_guard l(mutex_);
    queue_empty = queue_.empty();
  }
  maybe_shrink_content(queue_empty);
}

void StreamingReplica::upload_thread() {
  std::mt19937_64 rng(chaos_.seed);
  for (;;) {
    const Work work = wait_for_work();
    if (work == Work::stop) return;
    if (work == Work::growth_step) {  // only a growth to advance
      growth_step_in_gap();
      continue;
    }
    if (!wait_for_budget()) return;
    // Frame gaps (see frame_started()): wait for a gap the batch fits in, at most until its
    // oldest epoch has waited gap_wait_ms since its commit.
    GapWait gap;
    {
      std::unique_lock l(mutex_);
      if (!queue_.empty()) {
        gap = wait_for_gap(l, queue_.front().committed_at, policy_.batch_estimate_ms());
        if (gap.stop) return;
      }
    }
    std::uint32_t max_epochs = policy_.max_epochs_per_batch();
    if (chaos_.seed) {
      max_epochs = 1 + static_cast<std::uint32_t>(rng() % std::max(1u, chaos_.max_epochs_batch));
      std::this_thread::sleep_for(std::chrono::microseconds(rng() % (chaos_.max_delay_us + 1)));
    }
    std::vector<EpochUpload> batch;
    std::uint64_t bytes = 0;
    {
      std::lock_guard l(mutex_);
      const std::size_t take = UploadBatchPolicy::epochs_to_take(queue_.size(), max_epochs);
      for (std::size_t i = 0; i < take; ++i) {
        bytes += queue_.front().bytes();
        batch.push_back(std::move(queue_.front()));
        queue_.pop_front();
      }
    }
    if (batch.empty()) continue;
    const auto t_room = Clock::now();
    make_room(batch, max_epochs, bytes);
    ResidentBatch rb;
    rb.taken_at = Clock::now();
    rb.room_ms = ms_since(t_room);
    rb.bytes = bytes;
    rb.gap_wait_ms = gap.waited_ms;
    rb.mid_frame = gap.mid_frame;
    rb.in_gap = gap.scheduled && !gap.mid_frame;
    const Result<void> r = apply_batch(batch, max_epochs, rb);
    policy_.batch_done();
    policy_.batch_took(rb.content_ms + rb.gpu_lock_ms);
    policy_.spend_bytes(rb.bytes);
    record_batch(r, rb, batch.size(), bytes);
    if (r) after_batch();
  }
}

void StreamingReplica::attach_frames(bool attached) {
  {
    std::lock_guard l(mutex_);
    frames_.attach(attached);
  }
  cv_.notify_all();
}

void StreamingReplica::frame_started(double gap_wait_ms) {
  {
    std::lock_guard l(mutex_);
    frames_.frame_started(gap_wait_ms);
  }
  cv_.notify_all();
}

void StreamingReplica::frame_finished(SteadyTime next_frame_due) {
  {
    std::lock_guard l(mutex_);
    frames_.frame_finished(Clock::now(), next_frame_due);
  }
  cv_.notify_all();
}

bool StreamingReplica::wait_resident(std::uint64_t epoch, std::chrono::milliseconds timeout) {
  std::unique_lock l(mutex_);
  return cv_.wait_for(
             l, timeout,
             [&] { return (whole_resident_ && resident_epoch_ >= epoch) || !status_ || stop_; }) &&
         whole_resident_ && resident_epoch_ >= epoch;
}

bool StreamingReplica::wait_any_resident(std::chrono::milliseconds timeout) {
  std::unique_lock l(mutex_);
  return cv_.wait_for(l, timeout, [&] { return any_resident_ || !status_ || stop_; }) &&
         any_resident_;
}

std::uint64_t StreamingReplica::resident_epoch() const {
  std::lock_guard l(mutex_);
  return resident_epoch_;
}

bool StreamingReplica::any_resident() const {
  std::lock_guard l(mutex_);
  return any_resident_;
}

std::vector<ResidentBatch> StreamingReplica::take_resident_log() {
  std::lock_guard l(mutex_);
  return std::exchange(log_, {});
}

StreamingStats StreamingReplica::stats() const {
  std::lock_guard l(mutex_);
  return stats_;
}

Result<void> StreamingReplica::status() const {
  std::lock_guard l(mutex_);
  return status_;
}

EpochUpload capture_commit(const client_core::EpochCommit& c, std::uint32_t width_log2) {
  std::vector<ChangedRange> ranges;
  ranges.reserve(c.ranges.size() + c.changed_cells.size());
  for (const auto& r : c.ranges) ranges.push_back({r.first_cell, r.cell_count});
  for (const std::uint32_t cell : c.changed_cells) ranges.push_back({cell, 1});
  EpochUpload e = capture_epoch(c.replica.view(), c.epoch, width_log2, ranges, c.masked_groups);
  e.partial = c.partial;
  return e;
}

void stream_client_into(client_core::Client& client, StreamingReplica& replica) {
  client.set_epoch_listener([&replica](const client_core::EpochCommit& c) {
    replica.push(capture_commit(c, replica.width_log2()));
  });
}

}  // namespace deepcanvas::client_gpu
