#include "deepcanvas/storage/durable_canvas.hpp"

#include <algorithm>
#include <chrono>
#include <map>
#include <set>
#include <utility>

#include "deepcanvas/server_core/event_replay.hpp"
#include "deepcanvas/server_core/painter.hpp"

namespace deepcanvas::storage {

namespace {

bool same_shape(const server_core::OctreeConfig& a, const server_core::OctreeConfig& b) {
  return a.roots_per_axis == b.roots_per_axis && a.edge_m == b.edge_m &&
         a.max_depth == b.max_depth && a.block_cells == b.block_cells &&
         a.max_cells == b.max_cells;
}

Error in_canvas(const std::string& name, const std::string& path, const Error& e) {
  return Error{e.code, "canvas '" + name + "' (" + path + "): " + e.message};
}

}  // namespace

Result<std::unique_ptr<server_core::CanvasService>> open_durable_canvas(
    const std::string& dir, server_core::CanvasServiceConfig config, const StoreOptions& options,
    bool salvage, RestoreReport* report) {
  const auto t0 = std::chrono::steady_clock::now();
  RestoreReport local;
  RestoreReport& rep = report ? *report : local;
  auto opened = CanvasStore::open(dir, config.name, config.octree, options);
  if (!opened) return std::move(opened).error();
  std::shared_ptr<CanvasStore> store = std::move(*opened);
  rep.path = store->path();
  rep.created = store->created();
  if (!same_shape(store->config(), config.octree))
    rep.notes.push_back("the canvas keeps the shape it was created with (--edge " +
                        std::to_string(store->config().edge_m) + ", --roots " +
                        std::to_string(store->config().roots_per_axis) + ", --max-depth " +
                        std::to_string(store->config().max_depth) + ", --max-cells " +
                        std::to_string(store->config().max_cells) +
                        "); the options given for new canvases do not change it");
  config.octree = store->config();

  auto loaded = store->load(salvage);
  if (!loaded) return std::move(loaded).error();
  rep.checkpoint_id = loaded->checkpoint_id;
  rep.checkpoint_event_seq = loaded->checkpoint_event_seq;
  rep.stroke_names = std::move(loaded->stroke_names);
  for (auto& n : loaded->notes) rep.notes.push_back(std::move(n));
  std::unique_ptr<server_core::Octree> tree = std::move(loaded->tree);

  // The versions the checkpoint holds, before the replay changes them: the next checkpoint
  // holds the blocks that differ. Without a checkpoint the store holds no block at all.
  std::vector<std::uint64_t> versions;
  if (loaded->checkpoint_id != 0) {
    versions.resize(tree->block_count());
    for (server_core::BlockId b = 0; b < versions.size(); ++b)
      versions[b] = tree->block_state(b).version;
  }

  std::uint64_t last_seq = loaded->last_seq;
  std::uint64_t next_id = loaded->next_stroke_id;
  // The undo history as the checkpoint left it; the replay adds the strokes and undos after it.
  auto history = std::make_unique<server_core::UndoHistory>(config.undo);
  if (!loaded->undo_history.empty()) {
    auto h = server_core::UndoHistory::load(loaded->undo_history);
    if (h) {
      *history = std::move(*h);
      history->set_limits(config.undo);  // this start's bounds, not the saving server's
    } else
      rep.notes.push_back("the undo history of " + rep.path + " does not read (" +
                          h.error().message + "); undo starts with the strokes after it");
  }
  {
    auto painter = server_core::Painter::create(*tree, server_core::painter_config(config));
    if (!painter) return in_canvas(config.name, rep.path, painter.error());
    server_core::UndoHistory* undo = config.undo.depth > 0 ? history.get() : nullptr;
    const std::uint64_t first_step_work =
        std::min(config.max_cells_first_step, config.max_cells_per_step);
    const server_core::EventReplayTotals t = server_core::replay_stroke_events(
        **painter, loaded->events_after, first_step_work, undo);
    rep.events_replayed = t.events;
    next_id = std::max(next_id, t.max_stroke_id + 1);
    // Strokes cut off by the stop are ended now with what is durable, and the end recorded
    // (EndedBy::server: the sender's name stays unended), through replay_stroke_events as a
    // replay of the history will take it, so that the stroke's change is in the undo history.
    // Those and the strokes the server cut short before (a closed connection, the idle timeout)
    // are the unended names: a resend of one withdraws it first (cut_stroke_names), so that it
    // shows once and whole. A stroke that could not be ended here is not among them.
    std::set<std::uint64_t> still_open;
    for (const auto& [id, artist] : t.open) {
      server_core::StrokeEvent end;
      end.kind = server_core::StrokeEvent::Kind::end;
      end.stroke_id = id;
      end.artist = artist;  // the sender's stroke still: its undo is the sender's
      if (server_core::replay_stroke_events(**painter, {&end, 1}, first_step_work, undo)
              .strokes_ended == 0) {
        still_open.insert(id);
        continue;
      }
      last_seq = store->append(end, artist, server_core::EndedBy::server);
      ++rep.strokes_ended;
    }
    // A name a later stroke took (the resend that withdrew it, or the same handle's newer cut)
    // is not named again: that stroke answers the handle.
    std::map<std::pair<std::uint64_t, std::uint64_t>, std::uint64_t> newest;  // -> stroke id
    for (const auto* names : {&rep.stroke_names, &loaded->unended_names})
      for (const server_core::StrokeName& n : *names) {
        auto& id = newest[{n.artist, n.handle}];
        id = std::max(id, n.stroke_id);
      }
    for (const server_core::StrokeName& n : loaded->unended_names)
      if (!still_open.count(n.stroke_id) && newest[{n.artist, n.handle}] == n.stroke_id)
        rep.cut_stroke_names.push_back(n);
  }
  loaded->events_after.clear();
  rep.last_seq = last_seq;

  store->start();
  config.journal = store;
  server_core::CanvasService::RestoredCanvas restored;
  restored.tree = std::move(tree);
  restored.next_stroke_id = next_id;
  restored.last_seq = last_seq;
  restored.checkpoint_seq = loaded->checkpoint_event_seq;
  restored.checkpoint_versions = std::move(versions);
  restored.undo_history = std::move(history);
  auto svc = server_core::CanvasService::create(config, std::move(restored));
  if (!svc) return in_canvas(config.name, rep.path, svc.error());
  rep.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return svc;
}

Result<HistoryReplay> replay_history(const std::string& db_path,
                                     server_core::CanvasServiceConfig config,
                                     std::uint64_t until_seq) {
  auto history = read_history(db_path, until_seq);
  if (!history) return std::move(history).error();
  config.octree = history->config;
  const auto& events = history->events;
  auto tree = server_core::Octree::create(config.octree);
  if (!tree) return std::move(tree).error();
  HistoryReplay out;
  out.tree = std::move(*tree);
  auto painter = server_core::Painter::create(*out.tree, server_core::painter_config(config));
  if (!painter) return std::move(painter).error();
  // From the first event: the artists' bounded histories, as the live canvas kept them.
  server_core::UndoHistory undo_history(config.undo);
  out.totals = server_core::replay_stroke_events(
      **painter, events, std::min(config.max_cells_first_step, config.max_cells_per_step),
      config.undo.depth > 0 ? &undo_history : nullptr);
  out.last_seq = events.size();
  return out;
}

}  // namespace deepcanvas::storage
