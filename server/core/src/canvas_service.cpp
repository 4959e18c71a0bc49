// CanvasService: job intake and the compress thread (encode once, publish). The stroke thread
// (painter steps, epochs, staging): stroke_thread.cpp, its decisions in stroke_scheduler.hpp. The
// publish state and subscriptions: canvas_publish.cpp.
#include <algorithm>
#include <cmath>
#include <cstring>

#include "canvas_service_impl.hpp"
#include "deepcanvas/protocol/block_frame.hpp"
#include "deepcanvas/base/thread_name.hpp"
#include "deepcanvas/base/log.hpp"

namespace deepcanvas::server_core {

using base::log_event;
using base::LogLevel;

CanvasService::CanvasService(const CanvasServiceConfig& config)
    : config_(config), impl_(std::make_unique<Impl>()) {}

CanvasService::~CanvasService() {
  stop();
}

protocol::CanvasGeometry CanvasService::geometry() const noexcept {
  protocol::CanvasGeometry g;
  g.roots_per_axis = config_.octree.roots_per_axis;
  g.edge_m = config_.octree.edge_m;
  g.max_depth = config_.octree.max_depth;
  return g;
}

// ------------------------------------------------------------------------------------ staging

StagedBlock stage_block(Octree& tree, BlockId b) {
  StagedBlock s;
  const std::uint32_t bc = tree.config().block_cells;
  const std::uint64_t hw = tree.high_water_cells();
  s.block = b;
  s.version = tree.block_state(b).version;
  s.first_cell = b * bc;
  const std::uint64_t end = std::min<std::uint64_t>(std::uint64_t{b + 1} * bc, hw);
  s.cell_count = end > s.first_cell ? static_cast<std::uint32_t>(end - s.first_cell) : 0;
  const std::size_t c0 = s.first_cell, n = s.cell_count;
  const auto fc = tree.first_child_pool();
  const auto col = tree.colour_pool();
  const auto gp = tree.group_parent_pool();
  const auto gd = tree.group_depth_flags_pool();
  s.first_child.assign(fc.begin() + c0, fc.begin() + c0 + n);
  s.colour.assign(col.begin() + c0, col.begin() + c0 + n);
  s.group_parent.assign(gp.begin() + c0 / 8, gp.begin() + (c0 + n) / 8);
  s.depth_flags.assign(gd.begin() + c0 / 8, gd.begin() + (c0 + n) / 8);
  const auto mask = tree.neighbour_mask(b);
  s.mask.assign(mask.begin(), mask.end());
  tree.clear_neighbour_mask(b);
  // Its shallowest live groups: their depth, and a box around a few of them, spread evenly.
  std::size_t at_min = 0;
  for (const std::uint8_t df : s.depth_flags) {
    if (pool_layout::dc_group_is_free(df)) continue;
    const auto d = static_cast<std::uint8_t>(pool_layout::dc_depth_of(df));
    if (d < s.min_depth) {
      s.min_depth = d;
      at_min = 0;
    }
    if (d == s.min_depth) ++at_min;
  }
  const std::size_t stride =
      std::max<std::size_t>(1, (at_min + kShallowBoxSamples - 1) / kShallowBoxSamples);
  std::size_t seen = 0;
  bool any = false;
  for (std::size_t g = 0; g < s.depth_flags.size(); ++g) {
    const std::uint8_t df = s.depth_flags[g];
    if (pool_layout::dc_group_is_free(df) || pool_layout::dc_depth_of(df) != s.min_depth) continue;
    if (seen++ % stride != 0) continue;
    // A group below the roots is its parent's cube: its first cell's corner and twice that
    // cell's edge (one parent walk). The roots' groups are rows of the root grid: the boxes of
    // their first and last cells span them (root coordinates need no walk).
    const auto c = static_cast<CellIndex>(c0 + 8 * g);
    Aabb box = tree.bounds_m(tree.coord(c));
    if (c >= tree.root_count()) {
      const double e = 2 * (box.max.x - box.min.x);
      box.max = {box.min.x + e, box.min.y + e, box.min.z + e};
    } else {
      box.max = tree.bounds_m(tree.coord(c + 7)).max;
    }
    Aabb& u = s.shallow_box;
    if (!any) u = box;
    u.min = {std::min(u.min.x, box.min.x), std::min(u.min.y, box.min.y), std::min(u.min.z, box.min.z)};
    u.max = {std::max(u.max.x, box.max.x), std::max(u.max.y, box.max.y), std::max(u.max.z, box.max.z)};
    any = true;
  }
  return s;
}

// ------------------------------------------------------------------------------------ create

PainterConfig painter_config(const CanvasServiceConfig& config) {
  PainterConfig pc;
  pc.max_cells_per_step = config.max_cells_per_step;
  pc.limits = config.stroke_limits;
  pc.capacity_reserve = config.capacity_reserve;
  pc.stamps = config.stamps;
  pc.record_diffs = config.undo.depth > 0;
  pc.max_recording_bytes = config.undo.max_recording_bytes;
  return pc;
}

std::uint64_t canvas_memory_bound_bytes(const CanvasServiceConfig& config) {
  constexpr double kBytesPerCell = 11.625 * (2 + 1.0 / 3) + 8 + 8 + 4;
  auto bytes =
      static_cast<std::uint64_t>(kBytesPerCell * static_cast<double>(config.octree.max_cells));
  if (config.undo.depth > 0) bytes += config.undo.max_bytes + config.undo.max_recording_bytes * 3;
  return bytes;
}

Result<std::unique_ptr<CanvasService>> CanvasService::create(const CanvasServiceConfig& config) {
  return create(config, RestoredCanvas{});
}

Result<std::unique_ptr<CanvasService>> CanvasService::create(const CanvasServiceConfig& config,
                                                             RestoredCanvas restored) {
  if (!protocol::is_valid_canvas_name(config.name))
    return make_error(Errc::invalid_argument, "bad canvas name '" + config.name + "'");
  if (config.texture_width < 64 || (config.texture_width & (config.texture_width - 1)))
    return make_error(Errc::invalid_argument, "texture width must be a power of two >= 64");
  if (config.undo.depth > 0 && config.undo.max_bytes < config.undo.max_stroke_bytes)
    return make_error(Errc::invalid_argument,
                      "the undo history's memory (undo_max_bytes) must hold at least one stroke's "
                      "change (undo_max_stroke_bytes)");
  if (!(config.capacity_reserve >= 0.0 && config.capacity_reserve <= 0.5))
    return make_error(Errc::invalid_argument, "capacity reserve must be in [0, 0.5]");
  if (config.idle_stroke_timeout.count() <= 0)
    return make_error(Errc::invalid_argument, "idle stroke timeout must be positive");
  if (restored.tree && restored.tree->config().block_cells != config.octree.block_cells)
    return make_error(Errc::invalid_argument, "the restored tree's shape differs from the config's");
  auto tree = restored.tree ? Result<std::unique_ptr<Octree>>(std::move(restored.tree))
                            : Octree::create(config.octree);
  if (!tree) return std::move(tree).error();
  std::unique_ptr<CanvasService> svc(new CanvasService(config));
  Impl& m = *svc->impl_;
  m.self = svc.get();
  m.encoder = protocol::BlockEncoder(protocol::BlockEncodeOptions{
      .level = config.zstd_level, .transform = true, .compress = true});
  m.shared->metrics = &svc->metrics_;
  m.shared->zstd_level = config.zstd_level;
  m.tree = std::move(*tree);
  m.next_stroke_id = std::max<std::uint64_t>(1, restored.next_stroke_id);
  m.restored_last_seq = restored.last_seq;
  m.restored_checkpoint_seq = std::min(restored.checkpoint_seq, restored.last_seq);
  m.restored_checkpoint_versions = std::move(restored.checkpoint_versions);
  m.restored_undo_history = std::move(restored.undo_history);
  // Epoch 0: every block the fresh tree has, with full masks, so a late joiner gets the roots.
  (void)m.tree->take_dirty_blocks();
  StagedEpoch e0;
  e0.epoch = 0;
  for (BlockId b = 0; b < m.tree->block_count(); ++b) e0.blocks.push_back(stage_block(*m.tree, b));
  e0.staged_at = Clock::now();  // compress_wait_seconds (unset, it counted the clock's age)
  svc->metrics_.live_cells.set(static_cast<std::int64_t>(m.tree->stats().live_cells));
  {
    std::lock_guard lock(m.cmutex);
    m.staged.push_back(std::move(e0));
    m.compress_backlog = 1;
  }
  m.compress_thread = std::thread([&m] {
    base::set_thread_name("dc-compress");
    m.compress_main();
  });
  m.stroke_thread = std::thread([&m] {
    base::set_thread_name("dc-stroke");
    m.stroke_main();
  });
  // Return once epoch 0 is published, so a subscriber's first take() is a complete snapshot.
  bool published = false;
  {
    std::unique_lock lock(m.shared->mutex);
    published = m.shared->published_cv.wait_for(lock, std::chrono::seconds(60),
                                                [&] { return m.shared->published_any; });
  }
  if (!published)
    return make_error(Errc::internal, "canvas '" + config.name + "': epoch 0 was not published");
  return svc;
}

void CanvasService::stop() {
  Impl& m = *impl_;
  if (m.stopped.exchange(true)) return;
  {
    std::lock_guard lock(m.qmutex);
    m.stopping = true;
  }
  m.qcv.notify_all();
  if (m.stroke_thread.joinable()) m.stroke_thread.join();
  {
    std::lock_guard lock(m.cmutex);
    m.compress_stop = true;
  }
  m.ccv.notify_all();
  if (m.compress_thread.joinable()) m.compress_thread.join();
}

// ------------------------------------------------------------------------------------ intake

Result<std::uint64_t> CanvasService::Impl::enqueue(Job job, Admission admission) {
  std::uint64_t id = 0;
  {
    std::lock_guard lock(qmutex);
    if (stopping) return stopping_error();
    if (admission == Admission::bounded && jobs.size() >= self->config_.max_queued_jobs) {
      self->metrics_.rejected_jobs.add();
      return make_error(Errc::limit_exceeded, "the canvas's job queue is full");
    }
    if (self->config_.playback &&
        (job.kind == Job::Kind::stroke || job.kind == Job::Kind::begin ||
         job.kind == Job::Kind::undo || job.kind == Job::Kind::paste))
      return make_error(Errc::refused, "canvas '" + self->config_.name +
                                           "' plays back a recorded history: it takes no "
                                           "strokes, undos or imports");
    if (auto r = admit_stream_job(job); !r) return std::move(r).error();
    // Under the queue lock, so that stroke ids follow queue order.
    // An undo takes a place in the same order (its id orders it among the artist's strokes; it
    // names no stroke of its own).
    if (job.kind == Job::Kind::stroke || job.kind == Job::Kind::begin ||
        job.kind == Job::Kind::undo || job.kind == Job::Kind::paste)
      job.id = next_stroke_id++;
    if (job.kind == Job::Kind::begin) {
      protocol::SampleBox box;
      box.add(job.samples.span());
      open_streams.emplace(job.id, box);
    }
    if (job.kind == Job::Kind::pick_up) job.after_stroke = next_stroke_id - 1;
    id = job.id;
    jobs.push_back(std::move(job));
    self->metrics_.queue_depth.set(static_cast<std::int64_t>(jobs.size()));
  }
  qcv.notify_one();
  return id;
}

Result<void> CanvasService::Impl::admit_stream_job(Job& job) {
  if (job.kind != Job::Kind::samples && job.kind != Job::Kind::end) return {};
  auto it = open_streams.find(job.id);
  if (it == open_streams.end()) {
    for (const auto& [key, reason] : server_ended)
      if (key == job.id)
        return make_error(Errc::refused, "stroke " + std::to_string(key) + " is over: " + reason);
    return make_error(Errc::not_found, "no open streamed stroke " + std::to_string(job.id));
  }
  if (job.kind == Job::Kind::end) {
    open_streams.erase(it);
    return {};
  }
  protocol::SampleBox grown = it->second;
  grown.add(job.samples.span());
  if (auto r = protocol::check_extent(grown, self->config_.stroke_limits); !r)
    return make_error(Errc::limit_exceeded,
                      r.error().message + ": these samples were dropped, the stroke stays open");
  it->second = grown;
  return {};
}

bool CanvasService::Impl::end_stream_by_server(std::uint64_t key, const std::string& reason,
                                               bool only_if_idle) {
  std::lock_guard lock(qmutex);
  auto it = open_streams.find(key);
  if (it == open_streams.end()) return !only_if_idle;  // its end is queued already
  if (only_if_idle)
    for (const Job& j : jobs)
      if ((j.kind == Job::Kind::samples || j.kind == Job::Kind::end) && j.id == key) return false;
  open_streams.erase(it);
  server_ended.emplace_back(key, reason);
  if (server_ended.size() > kServerEndedRemembered) server_ended.pop_front();
  return true;
}

protocol::StrokeRules CanvasService::stroke_rules() const noexcept {
  return protocol::StrokeRules{protocol::CanvasBounds{config_.octree.edge_m},
                               config_.stroke_limits};
}

Result<void> CanvasService::submit_stroke(protocol::ValidatedStroke stroke,
                                          Clock::time_point received, AckFn done,
                                          std::uint64_t artist, std::uint64_t handle) {
  if (config_.journal)
    if (auto r = config_.journal->accepting(); !r) return r;
  const std::size_t samples = stroke.samples().size();
  Job j;
  j.kind = Job::Kind::stroke;
  j.artist = artist;
  j.handle = handle;
  j.brush = stroke.brush();
  j.samples = std::move(stroke).samples();
  j.received = received;
  j.done = std::move(done);
  if (auto r = impl_->enqueue(std::move(j), Impl::Admission::bounded); !r)
    return std::move(r).error();
  metrics_.samples.add(samples);
  return {};
}

Result<std::uint64_t> CanvasService::begin_stroke(const protocol::ValidatedBrush& brush,
                                                  protocol::ValidatedSamples samples,
                                                  Clock::time_point received, AckFn done,
                                                  std::uint64_t artist, std::uint64_t handle) {
  if (config_.journal)
    if (auto r = config_.journal->accepting(); !r) return std::move(r).error();
  const std::size_t n = samples.size();
  Job j;
  j.kind = Job::Kind::begin;
  j.artist = artist;
  j.handle = handle;
  j.brush = brush;
  j.samples = std::move(samples);
  j.received = received;
  j.done = std::move(done);
  auto id = impl_->enqueue(std::move(j), Impl::Admission::bounded);
  if (id) metrics_.samples.add(n);
  return id;
}

Result<void> CanvasService::add_samples(std::uint64_t key, protocol::ValidatedSamples samples) {
  const std::size_t n = samples.size();
  Job j;
  j.kind = Job::Kind::samples;
  j.id = key;
  j.samples = std::move(samples);
  if (auto r = impl_->enqueue(std::move(j), Impl::Admission::bounded); !r)
    return std::move(r).error();
  metrics_.samples.add(n);
  return {};
}

Result<void> CanvasService::end_stroke(std::uint64_t key, EndedBy by) {
  Job j;
  j.kind = Job::Kind::end;
  j.id = key;
  j.cut = by == EndedBy::server;
  j.received = Clock::now();
  // An end is always accepted (even past the queue bound) so that no stroke stays open.
  if (auto r = impl_->enqueue(std::move(j), Impl::Admission::always); !r)
    return std::move(r).error();
  return {};
}

Result<void> CanvasService::undo(std::uint64_t artist, bool redo, Clock::time_point received,
                                 UndoFn done, std::uint64_t stroke) {
  if (config_.journal)
    if (auto r = config_.journal->accepting(); !r) return r;
  Job j;
  j.kind = Job::Kind::undo;
  j.artist = artist;
  j.redo = redo;
  j.undo_stroke = redo ? 0 : stroke;
  j.received = received;
  j.undo_done = std::move(done);
  if (auto r = impl_->enqueue(std::move(j), Impl::Admission::bounded); !r)
    return std::move(r).error();
  return {};
}

Result<void> CanvasService::paste(std::uint64_t artist, std::shared_ptr<const CellPaste> cells,
                                  Clock::time_point received, ImportFn done) {
  if (!cells) return make_error(Errc::invalid_argument, "an import with no cells");
  if (config_.journal)
    if (auto r = config_.journal->accepting(); !r) return r;
  Job j;
  j.kind = Job::Kind::paste;
  j.artist = artist;
  j.received = received;
  j.paste = std::move(cells);
  j.import_done = std::move(done);
  if (auto r = impl_->enqueue(std::move(j), Impl::Admission::bounded); !r)
    return std::move(r).error();
  return {};
}

Result<void> CanvasService::copy_tree(TreeCopyFn done) {
  Job j;
  j.kind = Job::Kind::pick_up;  // ordered and answered like a pick-up
  j.copy_done = std::move(done);
  if (auto r = impl_->enqueue(std::move(j), Impl::Admission::bounded); !r)
    return std::move(r).error();
  return {};
}

Result<void> CanvasService::play(std::uint64_t operations, double seconds, PlaybackFn done) {
  if (!config_.playback)
    return make_error(Errc::unsupported,
                      "canvas '" + config_.name + "' does not play back a history (a canvas of "
                      "`deepcanvas-server playback` does)");
  if (seconds > 0 && !config_.playback->timed())
    return make_error(Errc::unsupported,
                      "this history has no painting times (a stroke log of strokes timed by "
                      "their own clocks): step by strokes");
  if (!std::isfinite(seconds) || seconds < 0)
    return make_error(Errc::invalid_argument, "a playback step's seconds must be finite, >= 0");
  Job j;
  j.kind = Job::Kind::pick_up;  // ordered and answered like a pick-up
  j.playback_done = std::move(done);
  j.playback_operations = operations;
  j.playback_seconds = seconds;
  if (auto r = impl_->enqueue(std::move(j), Impl::Admission::bounded); !r)
    return std::move(r).error();
  return {};
}

Result<void> CanvasService::pick_up(const protocol::PickUp& request, PickUpFn reply) {
  const double h = config_.octree.edge_m / 2;
  for (double v : request.position)
    if (!std::isfinite(v) || v < -h || v > h)
      return make_error(Errc::invalid_argument, "pick-up position outside the canvas");
  Job j;
  j.kind = Job::Kind::pick_up;
  j.pick = request;
  j.reply = std::move(reply);
  if (auto r = impl_->enqueue(std::move(j), Impl::Admission::bounded); !r)
    return std::move(r).error();
  return {};
}

Result<CanvasService::Quiescent> CanvasService::quiesce(std::chrono::milliseconds timeout) {
  Impl& m = *impl_;
  auto p = std::make_shared<std::promise<Result<Quiescent>>>();
  auto f = p->get_future();
  Job j;
  j.kind = Job::Kind::quiesce;
  j.quiesce = p;
  if (auto r = m.enqueue(std::move(j), Impl::Admission::always); !r) return std::move(r).error();
  if (f.wait_for(timeout) != std::future_status::ready)
    return make_error(Errc::io_error, "canvas did not quiesce in time");
  return f.get();
}

// ---------------------------------------------------------------------------- compress thread

// Encodes a staged epoch and publishes it; the caller runs se.after_publish. Each block gets a
// delta frame against its previous published version where there is one; the full frame is
// encoded now only where there is no delta or the delta is larger than the block's last full
// frame (scaled by its cell count: FullFrameSize; then the smaller of the two is kept), else
// deferred (PublishedFrame::full_bytes). Called on the compress thread, or on the stroke thread
// for a stroke's first epoch when the compress thread is idle; epochs are published in order
// because the stroke thread only does that when no epoch is queued or being encoded
// (compress_backlog == 0), and encode_mutex hands the encoder state between the two.
void CanvasService::Impl::encode_and_publish(StagedEpoch& se) {
  CanvasMetrics& metrics = self->metrics_;
  std::lock_guard encode_lock(encode_mutex);
  const auto t0 = Clock::now();
  std::vector<std::shared_ptr<const PublishedFrame>> frames;
  std::vector<std::shared_ptr<const PublishedFrame>> deferred;
  frames.reserve(se.blocks.size());
  for (StagedBlock& b : se.blocks) {
    if (b.cell_count == 0) continue;
    auto f = std::make_shared<PublishedFrame>();
    f->block = b.block;
    f->version = b.version;
    f->epoch = se.epoch;
    f->first_cell = b.first_cell;
    f->cell_count = b.cell_count;
    f->mask = b.mask;
    f->min_depth = b.min_depth;
    f->shallow_box = b.shallow_box;
    std::vector<std::uint8_t> delta;
    auto block = std::make_shared<const StagedBlock>(std::move(b));
    const protocol::BlockView v = view_of(*block, se.epoch);
    if (block->block >= previous.size()) {
      previous.resize(std::size_t{block->block} + 1);
      last_full.resize(previous.size());
    }
    auto& prev = previous[block->block];
    if (prev && prev->first_cell == block->first_cell && prev->cell_count <= block->cell_count &&
        prev->cell_count > 0 && prev->version < block->version &&
        block->version - prev->version <= 0xFFFFFFFFu &&
        encoder.encode_delta(v, view_of(*prev, se.epoch), delta).ok()) {
      f->base_version = prev->version;
    } else {
      delta.clear();
    }
    FullFrameSize& expected = last_full[block->block];
    if (expected.cells > 0)
      f->full_size_estimate = std::uint64_t{expected.bytes} * block->cell_count / expected.cells;
    if (!delta.empty() && expected.cells > 0 && delta.size() <= f->full_size_estimate) {
      f->defer_full_bytes(block, encoder.options());
      metrics.full_frames_deferred.add();
      deferred.push_back(f);
    } else {
      std::vector<std::uint8_t> full;
      if (auto r = encoder.encode(v, full); !r) {
        log_event(
            LogLevel::error, "encode_failed",
            {{"canvas", self->name()}, {"block", block->block}, {"error", r.error().message}});
        continue;
      }
      count_full_frame(metrics, block->cell_count, full.size());
      expected = {static_cast<std::uint32_t>(full.size()), block->cell_count};
      // A delta that is not smaller than the full frame is not worth a second path.
      if (delta.size() >= full.size()) {
        delta.clear();
        f->base_version = 0;
      }
      f->full_size_estimate = full.size();
      f->set_full_bytes(std::move(full));
    }
    const std::uint64_t sent_bytes = !delta.empty() ? delta.size() : f->full_size_estimate;
    if (se.steps == StagedEpoch::Steps::painting) metrics.epoch_bytes_painting.add(sent_bytes);
    if (se.steps == StagedEpoch::Steps::merging_only) metrics.epoch_bytes_merging.add(sent_bytes);
    if (!delta.empty()) {
      metrics.bytes_delta.add(delta.size());
      f->delta = std::make_shared<const std::vector<std::uint8_t>>(std::move(delta));
    }
    prev = std::move(block);
    frames.push_back(std::move(f));
  }
  metrics.compress_seconds.observe_seconds(
      std::chrono::duration<double>(Clock::now() - t0).count());
  const auto published_at = Clock::now();
  for (const auto& t : se.receipts)
    metrics.stroke_to_publish_seconds.observe_seconds(
        std::chrono::duration<double>(published_at - t).count());
  for (auto& f : deferred) deferred_full.emplace_back(published_at, f);
  shared->publish(se.epoch, std::move(frames), se.receipts);
  metrics.epochs.add();
  if (!deferred.empty()) {
    // Wakes the compress thread if it sleeps without a fill deadline (an inline publish).
    {
      std::lock_guard lock(cmutex);
      deferred_added = true;
    }
    ccv.notify_one();
  }
}

std::optional<Clock::time_point> CanvasService::Impl::fill_deferred_full(Clock::time_point now) {
  std::lock_guard encode_lock(encode_mutex);
  while (!deferred_full.empty()) {
    auto [published_at, weak] = deferred_full.front();
    auto f = weak.lock();
    // Superseded (a newer version is published: nobody will ask for this one's full frame) or
    // encoded already by a session that needed it.
    const bool wanted = f && !f->has_full_bytes() && f->block < previous.size() &&
                        previous[f->block] && previous[f->block]->version == f->version;
    if (!wanted) {
      deferred_full.pop_front();
      continue;
    }
    if (now < published_at + kFullFillDelay) return published_at + kFullFillDelay;
    deferred_full.pop_front();
    bool encoded_now = false;
    const auto& bytes = f->full_bytes(&encoded_now);
    if (encoded_now) self->metrics_.full_frames_filled.add();
    if (encoded_now && !bytes.empty()) {
      if (f->block < last_full.size())
        last_full[f->block] = {static_cast<std::uint32_t>(bytes.size()), f->cell_count};
      count_full_frame(self->metrics_, f->cell_count, bytes.size());
    }
    return now;  // one at a time: look at the staged queue again
  }
  return std::nullopt;
}

void CanvasService::Impl::compress_main() {
  CanvasMetrics& metrics = self->metrics_;
  for (;;) {
    StagedEpoch se;
    // Deferred full frames only while no epoch waits (they are off the latency path).
    bool idle = false;
    {
      std::lock_guard lock(cmutex);
      idle = staged.empty();
    }
    const std::optional<Clock::time_point> fill_due =
        idle ? fill_deferred_full(Clock::now()) : std::nullopt;
    {
      std::unique_lock lock(cmutex);
      const auto ready = [&] { return !staged.empty() || compress_stop || deferred_added; };
      if (fill_due)
        ccv.wait_until(lock, *fill_due, ready);
      else
        ccv.wait(lock, ready);
      deferred_added = false;
      if (staged.empty()) {
        if (compress_stop) return;
        continue;  // a deferred full frame is due
      }
      se = std::move(staged.front());
      staged.pop_front();
    }
    if (self->config_.before_compress) self->config_.before_compress(se.epoch);
    metrics.compress_wait_seconds.observe_seconds(
        std::chrono::duration<double>(Clock::now() - se.staged_at).count());
    encode_and_publish(se);
    // The epoch is published: the backlog drops before the replies waiting on the publish go
    // out (the stroke thread's backlog wait pairs with it).
    {
      std::lock_guard lock(qmutex);  // pairs with the stroke thread's backlog wait
      --compress_backlog;
      metrics.compress_queue.set(compress_backlog.load());
    }
    qcv.notify_all();
    for (auto& fn : se.after_publish) fn();
  }
}

// ------------------------------------------------------------------------------------ metrics

void CanvasService::write_metrics(PrometheusWriter& w) const {
  const std::string l = PrometheusWriter::label("canvas", name());
  const CanvasMetrics& m = metrics_;
  w.counter("deepcanvas_strokes_total", "Strokes completed (painted and fully adjusted).", l,
            m.strokes.value());
  w.counter("deepcanvas_samples_total", "Stroke samples received.", l, m.samples.value());
  w.counter("deepcanvas_cells_changed_total", "Cells created, freed or recoloured by strokes.", l,
            m.cells_changed.value());
  w.counter("deepcanvas_steps_total", "Painter adjustment steps.", l, m.steps.value());
  w.counter("deepcanvas_epochs_total", "Epochs published.", l, m.epochs.value());
  w.counter("deepcanvas_inline_epochs_total",
            "Epochs of those encoded and published on the stroke thread (the compress thread "
            "was idle).",
            l, m.inline_epochs.value());
  w.counter("deepcanvas_blocks_staged_total", "Blocks copied out of the tree into staged blocks.",
            l, m.blocks_staged.value());
  w.counter("deepcanvas_block_bytes_raw_total", "Block payload bytes before compression.", l,
            m.bytes_raw.value());
  w.counter("deepcanvas_block_bytes_compressed_total",
            "Block frame bytes after compression (full frames).", l, m.bytes_compressed.value());
  w.counter("deepcanvas_block_bytes_delta_total",
            "Temporal delta frame bytes after compression (blocks that got one).", l,
            m.bytes_delta.value());
  w.counter("deepcanvas_epoch_frame_bytes_painting_total",
            "Frame bytes an up-to-date subscriber is sent for epochs with a painting step.", l,
            m.epoch_bytes_painting.value());
  w.counter("deepcanvas_epoch_frame_bytes_merging_total",
            "Frame bytes an up-to-date subscriber is sent for epochs that only merged strokes "
            "back.",
            l, m.epoch_bytes_merging.value());
  w.counter("deepcanvas_full_frames_deferred_total",
            "Block versions published with a delta frame and the full frame left for later.", l,
            m.full_frames_deferred.value());
  w.counter("deepcanvas_full_frames_filled_total",
            "Deferred full frames encoded by the idle compress thread (others: on demand).", l,
            m.full_frames_filled.value());
  w.counter("deepcanvas_composed_delta_frames_total",
            "Delta frames made for one subscriber from the version it holds to the newest, in "
            "place of the versions it skipped.", l, m.composed_delta_frames.value());
  w.counter("deepcanvas_bundles_encoded_total",
            "Frame bundles encoded for live batches of subscribers that take bundles.", l,
            m.bundles_encoded.value());
  w.counter("deepcanvas_bundles_reused_total",
            "Live batches sent as bundles already encoded for another subscriber in step.", l,
            m.bundles_reused.value());
  w.counter("deepcanvas_bundled_frame_bytes_total",
            "Bytes the frames of live batches sent as bundles would have taken alone.", l,
            m.bundled_frame_bytes.value());
  w.counter("deepcanvas_bundle_bytes_total", "Bytes of the frame bundles sent instead.", l,
            m.bundle_bytes.value());
  w.counter("deepcanvas_jobs_rejected_total", "Jobs refused because the queue was full.", l,
            m.rejected_jobs.value());
  w.counter("deepcanvas_turns_throttled_total",
            "Times strokes with input waiting were held because their artist's cell growth "
            "budget was spent.", l, m.throttled_turns.value());
  w.counter("deepcanvas_undos_total", "Undos and redos done.", l, m.undos.value());
  w.counter("deepcanvas_undos_refused_total",
            "Undos and redos answered with an error (nothing to undo, history bound).", l,
            m.undos_refused.value());
  w.counter("deepcanvas_undo_recordings_dropped_total",
            "Strokes whose change recording was dropped to stay within the open strokes' budget "
            "(--undo-max-recording-bytes) or one recording's cap: they cannot be undone.",
            l, m.undo_recordings_dropped.value());
  w.counter("deepcanvas_imports_total", "Imports (volumes and meshes pasted as cells) applied.", l,
            m.imports.value());
  w.counter("deepcanvas_imports_refused_total", "Imports answered with an error.", l,
            m.imports_refused.value());
  w.gauge("deepcanvas_stroke_queue_depth", "Jobs waiting for the stroke thread.", l,
          static_cast<double>(m.queue_depth.value()));
  w.gauge("deepcanvas_compress_queue_depth", "Staged epochs waiting for the compress thread.", l,
          static_cast<double>(m.compress_queue.value()));
  w.gauge("deepcanvas_subscribers", "Sessions subscribed to the canvas.", l,
          static_cast<double>(m.subscribers.value()));
  w.gauge("deepcanvas_pending_blocks", "Blocks waiting to be sent, summed over sessions.", l,
          static_cast<double>(m.pending_blocks.value()));
  w.gauge("deepcanvas_live_cells", "Live cells in the canvas's tree.", l,
          static_cast<double>(m.live_cells.value()));
  w.gauge("deepcanvas_published_epoch", "The newest published epoch.", l,
          static_cast<double>(published_epoch()));
  w.histogram("deepcanvas_step_seconds", "Duration of one painter step.", l, m.step_seconds);
  w.histogram("deepcanvas_stage_seconds",
              "Stroke thread time copying one epoch's dirty blocks and masks (staging).", l,
              m.stage_seconds);
  w.histogram("deepcanvas_compress_seconds", "Encoding one epoch's blocks.", l, m.compress_seconds);
  w.histogram("deepcanvas_compress_wait_seconds",
              "A staged epoch waiting for the compress thread to start on it.", l,
              m.compress_wait_seconds);
  w.histogram("deepcanvas_stroke_to_stage_seconds",
              "Stroke received to the staging of its first blocks.", l, m.stroke_to_stage_seconds);
  w.histogram("deepcanvas_stroke_to_publish_seconds",
              "Stroke received to the publish of its first blocks.", l,
              m.stroke_to_publish_seconds);
  w.histogram("deepcanvas_end_to_painted_seconds",
              "stroke_end received to all of the stroke's paint in the tree (its ack's epoch).", l,
              m.end_to_painted_seconds);
  w.histogram("deepcanvas_painted_to_settled_seconds",
              "A stroke's paint complete to its uniform children merged back.", l,
              m.painted_to_settled_seconds);
  w.histogram("deepcanvas_undo_seconds", "One undo's or redo's revert on the stroke thread.", l,
              m.undo_seconds);
}

}  // namespace deepcanvas::server_core
