// CanvasService's publish side: the shared publish state, subscriptions (pending sets, snapshot,
// coalescing with mask OR) and the take() that hands a session a batch consistent at one epoch.
#include <algorithm>
#include <bit>
#include <tuple>

#include "canvas_service_impl.hpp"
#include "deepcanvas/base/log.hpp"
#include "deepcanvas/protocol/block_frame.hpp"
#include "deepcanvas/protocol/frame_bundle.hpp"

namespace deepcanvas::server_core {

using base::log_event;
using base::LogLevel;

struct Subscription::Pending {
  // Block id -> neighbour-mask bits accumulated over every version published since the last
  // take (OR of the versions' masks), so skipping versions never loses a recomputation.
  std::unordered_map<BlockId, std::vector<std::uint64_t>> blocks;
  bool snapshot = true;  // nothing taken yet: the first take is a full snapshot
  std::uint64_t sent_epoch = 0;
  // Delta subscribers: block id -> 1 + the version last given to this subscriber (0: none). A
  // delta frame is given only when this is exactly its base, so the receiver always holds it.
  bool delta = false;
  bool compose = false;  // skipped versions as one delta from the held version (subscribe())
  bool bundles = false;  // live batches as frame bundles (subscribe())
  std::vector<std::uint64_t> held;
  std::shared_ptr<std::function<void()>> notify;
  std::optional<protocol::JoinCamera> camera;  // set_camera(): orders a snapshot's blocks
};

namespace {

// Where a block goes in a snapshot for a subscriber with `camera` (PROTOCOL.md 4.4): shallowest
// first; of one depth, the blocks whose shallow box is wholly behind the camera after those in
// front of it; then nearest the eye first (squared distance from the eye to the box).
struct SnapshotKey {
  std::uint8_t min_depth = 255;
  bool behind = false;
  double distance2 = 0;
  BlockId block = 0;
  friend bool operator<(const SnapshotKey& a, const SnapshotKey& b) {
    return std::tie(a.min_depth, a.behind, a.distance2, a.block) <
           std::tie(b.min_depth, b.behind, b.distance2, b.block);
  }
};

SnapshotKey snapshot_key(const PublishedFrame& f, const protocol::JoinCamera* camera) {
  SnapshotKey k{f.min_depth, false, 0, f.block};
  if (!camera) return k;
  const Aabb& box = f.shallow_box;
  const double lo[3] = {box.min.x, box.min.y, box.min.z}, hi[3] = {box.max.x, box.max.y, box.max.z};
  double ahead = 0;  // the box's farthest reach along the view direction, from the eye
  for (int i = 0; i < 3; ++i) {
    const double e = camera->eye[i], d = camera->target[i] - e;
    const double nearest = std::clamp(e, lo[i], hi[i]);
    k.distance2 += (nearest - e) * (nearest - e);
    ahead += d * ((d >= 0 ? hi[i] : lo[i]) - e);
  }
  k.behind = ahead < 0;
  return k;
}

}  // namespace

Subscription::~Subscription() {
  if (!shared_) return;
  std::lock_guard lock(shared_->mutex);
  auto& subs = shared_->subs;
  subs.erase(std::remove(subs.begin(), subs.end(), this), subs.end());
  shared_->metrics->pending_blocks.add(-static_cast<std::int64_t>(pending_->blocks.size()));
  shared_->metrics->subscribers.set(static_cast<std::int64_t>(subs.size()));
}

void Subscription::set_camera(const protocol::JoinCamera& camera) {
  std::lock_guard lock(shared_->mutex);
  pending_->camera = camera;
}

std::size_t Subscription::pending_blocks() const {
  std::lock_guard lock(shared_->mutex);
  return pending_->snapshot ? shared_->latest.size() : pending_->blocks.size();
}

std::uint64_t Subscription::sent_epoch() const {
  std::lock_guard lock(shared_->mutex);
  return pending_->sent_epoch;
}

void PublishedFrame::set_full_bytes(std::vector<std::uint8_t> bytes) {
  full_ = std::move(bytes);
  full_done_.store(true, std::memory_order_release);
}

void PublishedFrame::defer_full_bytes(std::shared_ptr<const StagedBlock> source,
                                      protocol::BlockEncodeOptions options) {
  source_ = std::move(source);
  full_options_ = options;
}

const std::vector<std::uint8_t>& PublishedFrame::full_bytes(bool* encoded_now) const {
  if (encoded_now) *encoded_now = false;
  if (full_done_.load(std::memory_order_acquire)) return full_;
  std::lock_guard lock(full_mutex_);
  if (full_done_.load(std::memory_order_relaxed)) return full_;
  // One encoder per thread and options (sessions' network threads, the compress thread).
  thread_local std::optional<protocol::BlockEncoder> encoder;
  const auto same = [](const protocol::BlockEncodeOptions& a,
                       const protocol::BlockEncodeOptions& b) {
    return a.level == b.level && a.transform == b.transform && a.compress == b.compress;
  };
  if (!encoder || !same(encoder->options(), full_options_)) encoder.emplace(full_options_);
  if (source_) {
    if (auto r = encoder->encode(view_of(*source_, epoch), full_); !r) {
      full_.clear();
      log_event(LogLevel::error, "encode_failed",
                {{"block", block}, {"version", version}, {"error", r.error().message}});
    }
  }
  source_.reset();  // the service keeps the newest version for the next delta anyway
  full_done_.store(true, std::memory_order_release);
  if (encoded_now) *encoded_now = true;
  return full_;
}

namespace {

// A mask-only frame: the receiver ORs these bits into the block's mask for this epoch.
FramePtr mask_frame(const PublishedFrame& f, const std::vector<std::uint64_t>& mask) {
  thread_local protocol::BlockEncoder encoder(
      protocol::BlockEncodeOptions{.level = 1, .transform = false, .compress = false});
  protocol::BlockView v;
  v.block_id = f.block;
  v.version = f.version;
  v.epoch = f.epoch;
  v.first_cell = f.first_cell;
  v.cell_count = f.cell_count;
  const std::size_t words = (f.cell_count / 8 + 63) / 64;
  v.neighbour_mask = std::span<const std::uint64_t>(mask.data(), std::min(words, mask.size()));
  auto out = std::make_shared<std::vector<std::uint8_t>>();
  if (mask.size() < words || !encoder.encode(v, *out)) return nullptr;
  return out;
}

// The versions a subscriber skipped as ONE delta frame, from the version it holds to the newest
// (`chain`: their deltas, oldest first, each against the one before). A cell differs between the
// held and the newest version only if some link of the chain marked it, so the union of the
// links' bitmaps with the newest values (from its full frame) is that delta (PROTOCOL.md 4.7).
// A link's bitmaps cover its own range, a prefix of the newest's; past a link's range its base
// counts as 0, so a cell the block gained is marked where it first became non-zero. nullptr when
// a frame does not decode (then the chain is sent as it is).
FramePtr composed_delta(const PublishedFrame& newest,
                        const std::vector<CanvasService::Shared::DeltaLink>& chain, int level) {
  const auto& full = newest.full_bytes();
  if (full.empty() || chain.empty()) return nullptr;
  thread_local protocol::BlockDecoder decoder;
  thread_local protocol::BlockFrame latest, link;
  if (!decoder.decode(full, latest)) return nullptr;
  const std::size_t cells = latest.header.cell_count, groups = cells / 8;
  std::vector<std::uint64_t> changed_cells((cells + 63) / 64, 0),
      changed_groups((groups + 63) / 64, 0);
  const auto or_into = [](std::vector<std::uint64_t>& into,
                          const std::vector<std::uint64_t>& from) {
    if (from.size() > into.size()) return false;
    for (std::size_t i = 0; i < from.size(); ++i) into[i] |= from[i];
    return true;
  };
  for (const auto& l : chain) {
    if (!decoder.decode(*l.delta, link) || !link.is_delta() ||
        link.header.first_cell != latest.header.first_cell ||
        link.header.fields != latest.header.fields || !or_into(changed_cells, link.changed_cells) ||
        !or_into(changed_groups, link.changed_groups))
      return nullptr;
  }
  thread_local std::optional<protocol::BlockEncoder> encoder;
  if (!encoder || encoder->options().level != level)
    encoder.emplace(
        protocol::BlockEncodeOptions{.level = level, .transform = true, .compress = true});
  auto out = std::make_shared<std::vector<std::uint8_t>>();
  const protocol::BlockChanges changes{chain.front().base_version, changed_cells, changed_groups};
  if (!encoder->encode_changes(protocol::view_of(latest), changes, *out)) return nullptr;
  return out;
}

// Which frames of a live batch go into bundles: those of at most kMaxBundledFrameRaw raw bytes
// (delta and mask-only frames, small full ones), until the batch's records reach
// kMaxBundledBatchRaw; the others go alone, in their place. Bundling is done on a network thread
// that other sessions share (their acks among them): a batch of whole blocks, hundreds of
// kilobytes to compress at once, held an ack back by 50 ms, and gains little from bundling (a
// full frame's header is a small part of it). The bound also keeps a bundle made for one
// subscriber out of step (its own, where frames are shared) small.
constexpr std::uint32_t kMaxBundledFrameRaw = 16 * 1024;
constexpr std::size_t kMaxBundledBatchRaw = 512 * 1024;

// A live batch's frames, the small ones as frame bundles (PROTOCOL.md 4.12). Subscribers in step
// take the same frames at every epoch: the bundles made last are reused when the frames are the
// same (mask-only frames are made for each take: compared by their bytes, far cheaper than
// compressing them again). Where a frame cannot be bundled (logged; never expected of frames
// this server made), the frames go as they are.
void bundle_frames(CanvasService::Shared& shared, Subscription::Batch& batch) {
  std::lock_guard lock(shared.bundle_mutex);
  const bool same = std::equal(
      batch.frames.begin(), batch.frames.end(), shared.bundle_key.begin(), shared.bundle_key.end(),
      [](const FramePtr& a, const FramePtr& b) { return a == b || *a == *b; });
  if (same) {
    shared.metrics->bundles_reused.add();
  } else {
    thread_local std::optional<protocol::BundleEncoder> encoder;
    thread_local int encoder_level = 0;
    if (!encoder || encoder_level != shared.zstd_level) {
      encoder.emplace(shared.zstd_level);
      encoder_level = shared.zstd_level;
    }
    std::vector<FramePtr> out;
    std::size_t bundled_raw = 0;
    const auto flush = [&]() -> Result<void> {
      if (encoder->records() == 0) return {};
      auto bundle = std::make_shared<std::vector<std::uint8_t>>();
      if (auto r = encoder->finish(*bundle); !r) return r;
      shared.metrics->bundles_encoded.add();
      out.push_back(std::move(bundle));
      return {};
    };
    for (const FramePtr& f : batch.frames) {
      const auto header = protocol::parse_block_header(*f);
      Result<void> r;
      if (header && header->raw_size <= kMaxBundledFrameRaw &&
          bundled_raw + header->raw_size <= kMaxBundledBatchRaw) {
        bundled_raw += header->raw_size;
        r = encoder->add(*f);
      } else {
        r = flush();
        out.push_back(f);
      }
      if (!r) {
        log_event(LogLevel::error, "bundle_failed", {{"error", r.error().message}});
        encoder.reset();  // drops the records added so far
        return;
      }
    }
    if (auto r = flush(); !r) {
      log_event(LogLevel::error, "bundle_failed", {{"error", r.error().message}});
      encoder.reset();
      return;
    }
    shared.bundle_key = batch.frames;
    shared.bundle_value = std::move(out);
  }
  shared.metrics->bundled_frame_bytes.add(batch.frame_bytes);
  batch.frames = shared.bundle_value;
  batch.frame_bytes = 0;
  for (const FramePtr& b : batch.frames) batch.frame_bytes += b->size();
  shared.metrics->bundle_bytes.add(batch.frame_bytes);
}

}  // namespace

std::optional<Subscription::Batch> Subscription::take() {
  struct Extra {
    std::shared_ptr<const PublishedFrame> frame;
    std::vector<std::uint64_t> mask;
  };
  struct Chosen {
    std::shared_ptr<const PublishedFrame> frame;
    // Delta frames to send instead of the full frame, oldest first: the block's own delta, or
    // the deltas of the versions the subscriber skipped, ending with it. Copies: publish() may
    // trim the chain once the lock is released.
    std::vector<CanvasService::Shared::DeltaLink> deltas;
    std::uint64_t full_size_estimate = 0;
    bool compose = false;
  };
  Batch batch;
  std::vector<Chosen> chosen;
  std::vector<Extra> extras;
  bool bundles = false;
  {
    std::lock_guard lock(shared_->mutex);
    Pending& p = *pending_;
    bundles = p.bundles;
    const std::uint64_t epoch = shared_->epoch;
    if (!p.snapshot && p.blocks.empty() && epoch == p.sent_epoch) return std::nullopt;
    if (p.snapshot && !shared_->published_any) return std::nullopt;
    batch.epoch = epoch;
    batch.caught_up = true;
    batch.snapshot = p.snapshot;
    std::vector<BlockId> ids;
    if (p.snapshot) {
      // Shallowest first (PROTOCOL.md 4.4, progressive join): a client that renders the blocks
      // it has, each missing subtree shown as its parent's filtered value, sees the whole canvas
      // coarse after the first few blocks and then finer as the deeper ones arrive; of one
      // depth, what is in front of its camera and near it first.
      std::vector<SnapshotKey> keys;
      const protocol::JoinCamera* camera = p.camera ? &*p.camera : nullptr;
      for (BlockId b = 0; b < shared_->latest.size(); ++b)
        if (shared_->latest[b]) keys.push_back(snapshot_key(*shared_->latest[b], camera));
      std::sort(keys.begin(), keys.end());
      ids.reserve(keys.size());
      for (const SnapshotKey& k : keys) ids.push_back(k.block);
    } else {
      ids.reserve(p.blocks.size());
      for (const auto& [b, m] : p.blocks) ids.push_back(b);
      std::sort(ids.begin(), ids.end());
    }
    chosen.reserve(ids.size());
    for (BlockId b : ids) {
      const auto& f = shared_->latest[b];
      if (!f) continue;
      const std::uint64_t held = b < p.held.size() ? p.held[b] : 0;  // 1 + version, 0: none
      Chosen c{f, {}};
      if (p.delta && f->delta && held > 0 && b < shared_->delta_chain.size()) {
        // The chain's tail from the version held (its last link is this version's delta), if
        // all of it is still kept and it weighs no more than the full frame. A single link
        // always does: publish kept that delta only if so.
        const auto& chain = shared_->delta_chain[b];
        std::uint64_t bytes = 0;
        for (const auto& link : chain) {
          if (c.deltas.empty() && link.base_version + 1 != held) continue;
          bytes += link.delta->size();
          c.deltas.push_back(link);
        }
        if (c.deltas.empty() || c.deltas.back().version != f->version ||
            (bytes > f->full_size_estimate && (c.deltas.size() < 2 || !p.compose)))
          c.deltas.clear();
        // A longer chain may still go as one composed delta (after the lock), or else as the
        // full frame where it weighs more.
        c.full_size_estimate = f->full_size_estimate;
        c.compose = p.compose;
      }
      chosen.push_back(std::move(c));
      if (p.delta) {
        if (b >= p.held.size()) p.held.resize(std::size_t{b} + 1, 0);
        p.held[b] = f->version + 1;
      }
      if (p.snapshot) {
        // A new replica has no links at all: every group of the block must be computed.
        extras.push_back({f, std::vector<std::uint64_t>(f->mask.size(), ~std::uint64_t{0})});
        continue;
      }
      const auto& acc = p.blocks[b];
      bool extra = false;
      for (std::size_t w = 0; w < acc.size() && w < f->mask.size(); ++w)
        if (acc[w] & ~f->mask[w]) extra = true;
      if (extra) extras.push_back({f, acc});
    }
    if (!p.snapshot)
      for (const auto& [e, t] : shared_->receipts_log)
        if (e > p.sent_epoch && e <= epoch) batch.stroke_receipts.push_back(t);
    shared_->metrics->pending_blocks.add(-static_cast<std::int64_t>(p.blocks.size()));
    p.blocks.clear();
    p.snapshot = false;
    p.sent_epoch = epoch;
  }
  // Full frames not encoded yet, and mask-only frames, are encoded outside the lock.
  batch.frames.reserve(chosen.size() + extras.size());
  for (const Chosen& c : chosen) {
    const PublishedFrame& f = *c.frame;
    bool send_chain = !c.deltas.empty();
    if (c.deltas.size() >= 2 && c.compose) {
      // Skipped versions: one delta from the held version when it weighs less than the chain
      // and the full frame; else the lighter of those two.
      std::uint64_t chain_bytes = 0;
      for (const auto& link : c.deltas) chain_bytes += link.delta->size();
      if (FramePtr one = composed_delta(f, c.deltas, shared_->zstd_level);
          one && one->size() < std::min(chain_bytes, c.full_size_estimate)) {
        batch.frame_bytes += one->size();
        batch.raw_bytes += protocol::block_payload_size(f.cell_count, protocol::kFieldAll);
        ++batch.delta_frames;
        shared_->metrics->composed_delta_frames.add();
        batch.frames.push_back(std::move(one));
        continue;
      }
      send_chain = chain_bytes <= c.full_size_estimate;
    }
    for (const auto& link : c.deltas) {
      if (!send_chain) break;
      batch.frames.push_back(link.delta);
      batch.frame_bytes += link.delta->size();
      batch.raw_bytes += link.payload_bytes;
      ++batch.delta_frames;
    }
    if (send_chain) continue;
    bool encoded_now = false;
    const auto& bytes = f.full_bytes(&encoded_now);
    if (encoded_now && !bytes.empty())
      count_full_frame(*shared_->metrics, f.cell_count, bytes.size());
    if (bytes.empty()) continue;  // could not be encoded (logged): never an empty frame
    batch.frames.emplace_back(c.frame, &bytes);
    batch.frame_bytes += bytes.size();
    batch.raw_bytes += protocol::block_payload_size(f.cell_count, protocol::kFieldAll);
  }
  for (const Extra& e : extras) {
    FramePtr f = mask_frame(*e.frame, e.mask);
    if (!f) continue;
    batch.frame_bytes += f->size();
    batch.raw_bytes += f->size() - protocol::kBlockHeaderSize;  // stored uncompressed
    batch.frames.push_back(std::move(f));
  }
  batch.block_frames = static_cast<std::uint32_t>(batch.frames.size());
  if (bundles && !batch.snapshot && !batch.frames.empty()) bundle_frames(*shared_, batch);
  return batch;
}

std::shared_ptr<Subscription> CanvasService::subscribe(std::function<void()> notify,
                                                       bool delta_frames, bool compose_skipped,
                                                       bool bundles) {
  std::shared_ptr<Subscription> sub(new Subscription());
  sub->shared_ = impl_->shared;
  sub->pending_ = std::make_unique<Subscription::Pending>();
  sub->pending_->delta = delta_frames;
  sub->pending_->compose = delta_frames && compose_skipped;
  sub->pending_->bundles = bundles;
  sub->pending_->notify = std::make_shared<std::function<void()>>(std::move(notify));
  auto n = sub->pending_->notify;
  {
    std::lock_guard lock(impl_->shared->mutex);
    impl_->shared->subs.push_back(sub.get());
    metrics_.subscribers.set(static_cast<std::int64_t>(impl_->shared->subs.size()));
  }
  if (*n) (*n)();  // the snapshot is ready now (or take() waits for epoch 0, then notifies)
  return sub;
}

std::uint64_t CanvasService::published_epoch() const {
  std::lock_guard lock(impl_->shared->mutex);
  return impl_->shared->epoch;
}

// Called on the compress thread with an epoch's encoded frames.
void CanvasService::Shared::publish(std::uint64_t new_epoch,
                                    std::vector<std::shared_ptr<const PublishedFrame>> frames,
                                    const std::vector<Clock::time_point>& receipts) {
  std::vector<std::shared_ptr<std::function<void()>>> to_notify;
  {
    std::lock_guard lock(mutex);
    std::int64_t added = 0;
    for (auto& f : frames) {
      if (f->block >= latest.size()) latest.resize(f->block + 1);
      if (f->block >= delta_chain.size()) delta_chain.resize(f->block + 1);
      auto& chain = delta_chain[f->block];
      if (!f->delta || (!chain.empty() && chain.back().version != f->base_version)) chain.clear();
      if (f->delta) {
        chain.push_back({f->version, f->base_version, f->delta,
                         protocol::block_payload_size(f->cell_count, protocol::kFieldAll)});
        if (chain.size() > kMaxDeltaChain) chain.pop_front();
      }
      for (Subscription* s : subs) {
        Subscription::Pending& p = *s->pending_;
        if (p.snapshot) continue;  // its snapshot will take the newest anyway
        auto [it, inserted] = p.blocks.try_emplace(f->block);
        if (inserted) {
          it->second = f->mask;
          ++added;
        } else {
          auto& acc = it->second;
          if (acc.size() < f->mask.size()) acc.resize(f->mask.size(), 0);
          for (std::size_t w = 0; w < f->mask.size(); ++w) acc[w] |= f->mask[w];
        }
      }
      latest[f->block] = std::move(f);
    }
    epoch = new_epoch;
    published_any = true;
    for (const auto& t : receipts) receipts_log.emplace_back(new_epoch, t);
    while (receipts_log.size() > 4096) receipts_log.pop_front();
    metrics->pending_blocks.add(added);
    to_notify.reserve(subs.size());
    for (Subscription* s : subs) to_notify.push_back(s->pending_->notify);
  }
  published_cv.notify_all();
  for (auto& n : to_notify)
    if (*n) (*n)();
}

}  // namespace deepcanvas::server_core
