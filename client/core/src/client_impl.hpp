// Client::Impl: the connection's state and its I/O thread's handlers (see client.hpp for the
// contract). Private to client_core: client.cpp (connect, close) and client_requests.cpp (the
// requests and waits of the public API) share it.
#pragma once

#include "client_tls.hpp"
#include "deepcanvas/client_core/client.hpp"
#include "deepcanvas/base/thread_name.hpp"
#include "deepcanvas/protocol/frame_bundle.hpp"

#include <bit>
#include <boost/asio.hpp>
#include <boost/asio/ssl.hpp>
#include <boost/beast.hpp>
#include <boost/beast/ssl.hpp>
#include <condition_variable>
#include <deque>
#include <future>
#include <map>
#include <mutex>
#include <thread>
#include <variant>

namespace deepcanvas::client_core {

namespace beast = boost::beast;
namespace http = beast::http;
namespace websocket = beast::websocket;
namespace net = boost::asio;
using tcp = net::ip::tcp;
using Clock = std::chrono::steady_clock;

using PlainWs = websocket::stream<beast::tcp_stream>;
using TlsWs = websocket::stream<beast::ssl_stream<beast::tcp_stream>>;
using detail::make_tls_context;
using detail::parse_url;
using detail::tls_handshake;

struct Client::Impl : std::enable_shared_from_this<Client::Impl> {
  // tls_context: null for ws://. Declared before the stream, which uses it until destroyed.
  explicit Impl(std::unique_ptr<net::ssl::context> tls_context)
      : tls(std::move(tls_context)), ws(make_ws(ioc, tls.get())) {}

  static std::variant<PlainWs, TlsWs> make_ws(net::io_context& ioc, net::ssl::context* ctx) {
    if (ctx) return std::variant<PlainWs, TlsWs>(std::in_place_type<TlsWs>, ioc, *ctx);
    return std::variant<PlainWs, TlsWs>(std::in_place_type<PlainWs>, ioc);
  }
  // Runs fn on the stream, whichever kind it is (one code path for ws:// and wss://).
  template <class F>
  decltype(auto) with_ws(F&& fn) {
    return std::visit(std::forward<F>(fn), ws);
  }
  beast::tcp_stream& tcp() {
    return with_ws([](auto& w) -> beast::tcp_stream& { return beast::get_lowest_layer(w); });
  }

  net::io_context ioc;
  std::unique_ptr<net::ssl::context> tls;
  std::variant<PlainWs, TlsWs> ws;
  std::thread io_thread;
  beast::flat_buffer rbuf;
  protocol::BlockDecoder decoder;
  protocol::BundleDecoder bundle_decoder;
  std::vector<protocol::BlockFrame> bundled;  // a bundle's frames, decoded before staging
  protocol::Welcome welcome;
  bool keep_replica = true;
  bool block_frames = true;  // asked for the canvas stream (ClientOptions::block_frames)

  // Write queue (I/O thread only).
  struct Out {
    std::string text;
    std::vector<std::uint8_t> binary;
    bool is_binary = false;
  };
  std::deque<Out> out;
  bool writing = false;
  bool paused = false;
  bool reading = false;
  bool failed = false;  // a protocol error closed (is closing) the connection with 1002
  // A close handshake is in flight (ours: close() or protocol_failure). Beast allows one close
  // at a time, and what arrives while it runs is not used: the caller is leaving or the stream
  // is already broken.
  bool closing = false;

  // Shared with callers.
  mutable std::mutex mutex;
  std::condition_variable cv;
  std::unique_ptr<Replica> replica;
  std::uint64_t applied_epoch = 0;
  std::map<std::uint64_t, protocol::Ack> acks;
  std::map<std::uint64_t, protocol::PickUpReply> picks;
  // Undo and redo answers by request id: the reply, or the error that replaced it.
  std::map<std::uint64_t, Result<protocol::UndoReply>> undos;
  // Import answers by request id.
  std::map<std::uint64_t, Result<protocol::ImportReply>> imports;
  // Export answers by request id.
  std::map<std::uint64_t, Result<protocol::ExportReply>> exports;
  // Playback step answers by request id.
  std::map<std::uint64_t, Result<protocol::PlaybackPosition>> playbacks;

  // Waits for (and takes) the answer to request `id` in `answers` (undos, imports, exports).
  template <class T>
  Result<T> take_answer(std::map<std::uint64_t, Result<T>>& answers, std::uint64_t id,
                        std::chrono::milliseconds timeout, const char* what) {
    std::unique_lock lock(mutex);
    cv.wait_for(lock, timeout, [&] { return answers.count(id) || !open; });
    auto it = answers.find(id);
    if (it == answers.end())
      return make_error(Errc::io_error, std::string("no answer to ") + what + " request " +
                                            std::to_string(id));
    Result<T> r = std::move(it->second);
    answers.erase(it);
    return r;
  }
  // Sends a request whose request_id is set here; returns that id.
  template <class M>
  Result<std::uint64_t> send_request(M m) {
    const std::uint64_t id = take_handle();
    m.request_id = id;
    auto r = send(std::move(m));
    if (!r) return std::move(r).error();
    return id;
  }
  std::optional<protocol::Stats> last_stats;
  std::map<std::uint64_t, protocol::PresenceUpdate> presence;  // other artists, by artist id
  std::uint64_t presence_updates = 0;
  std::deque<protocol::ErrorMessage> errors;
  ClientStats stats;
  bool open = true;
  int close_code = 0;
  std::uint64_t next_handle = 1;
  std::deque<std::pair<std::uint64_t, Clock::time_point>> first_frames;  // (epoch, arrival)
  std::uint64_t last_frame_epoch = 0;
  // Epoch listener (set_epoch_listener) and what the staged frames carry, for it.
  std::function<void(const EpochCommit&)> epoch_listener;
  std::vector<CommittedRange> staged_ranges;
  std::vector<std::uint32_t> staged_masked_groups;
  // Progressive join (ClientOptions::progressive_join): the snapshot's first frame, the last
  // partial commit, and the frames received by then.
  bool progressive_join = true;
  Clock::duration progressive_first{};
  Clock::time_point snapshot_started{}, last_partial{};
  std::uint64_t snapshot_frames = 0, frames_at_last_partial = 0;

  // ---------------------------------------------------------------- I/O thread

  void start_reading() {
    if (reading || paused) return;
    reading = true;
    with_ws([&](auto& w) {
      w.async_read(rbuf, [self = shared_from_this()](beast::error_code ec, std::size_t n) {
        self->on_read(ec, n);
      });
    });
  }

  void on_read(beast::error_code ec, std::size_t) {
    reading = false;
    if (ec) return ended(ec);
    if (closing) return;  // the close handshake reads on to the peer's close frame
    const auto data = rbuf.cdata();
    const std::span<const std::uint8_t> bytes(static_cast<const std::uint8_t*>(data.data()),
                                              data.size());
    if (with_ws([](auto& w) { return w.got_binary(); })) {
      on_frame(bytes);
    } else {
      on_text(std::string_view(reinterpret_cast<const char*>(bytes.data()), bytes.size()));
    }
    rbuf.consume(rbuf.size());
    if (failed) return;  // closing with 1002: read nothing more
    start_reading();
  }

  // A block frame this client cannot use (PROTOCOL.md 4.5, 4.7): the stream is broken from here
  // on (a later delta may build on the frame we dropped), so close with 1002 and tell the caller
  // through wait_for_error (a fatal, local error). The replica keeps the last committed epoch:
  // the frames staged for the open batch are never applied. Mutex held.
  void protocol_failure(std::string message) {
    ++stats.decode_failures;
    if (failed) return;
    failed = true;
    close_code = static_cast<int>(websocket::close_code::protocol_error);
    protocol::ErrorMessage e;
    e.code = Errc::malformed;
    e.message = "client closed the connection (1002): " + std::move(message);
    e.in_reply_to = "block_frame";
    e.fatal = true;
    errors.push_back(std::move(e));
    cv.notify_all();
    if (closing) return;  // close() already started the handshake
    closing = true;
    with_ws([&](auto& w) {
      w.async_close(websocket::close_code::protocol_error,
                    [self = shared_from_this()](beast::error_code ec) { self->ended(ec); });
    });
  }

  void on_frame(std::span<const std::uint8_t> bytes) {
    if (protocol::is_bundle(bytes)) return on_bundle(bytes);
    protocol::BlockFrame frame;
    protocol::BlockDecodeLimits limits;
    limits.max_cells = welcome.block_cells;
    limits.block_cells = welcome.block_cells;
    // Without a replica only the header is read (checked like any header): decompressing and
    // checksumming a payload nobody uses cost a load generator (and the e2e bench's painter,
    // which shares the CPUs with the server and the viewer) as much as the viewer's decoding.
    auto read = [&]() -> Result<void> {
      if (keep_replica) return decoder.decode(bytes, frame, limits);
      auto h = protocol::parse_block_header(bytes, limits);
      if (!h) return std::move(h).error();
      frame.header = *h;
      return {};
    };
    const auto r = read();
    std::lock_guard lock(mutex);
    if (failed) return;
    if (!r) return protocol_failure("undecodable block frame: " + r.error().message);
    stats.frame_bytes += bytes.size();
    stats.header_bytes += protocol::kBlockHeaderSize;
    accept_frame(std::move(frame));
  }

  // A frame bundle (PROTOCOL.md 4.12): its frames, decoded first (outside the mutex, like a
  // frame), then accepted one by one as if each had come alone. Without a replica only the header
  // is read: it counts the frames and names the newest epoch.
  void on_bundle(std::span<const std::uint8_t> bytes) {
    protocol::BundleDecodeLimits limits;
    limits.block.max_cells = welcome.block_cells;
    limits.block.block_cells = welcome.block_cells;
    std::size_t decoded = 0;
    auto read = [&]() -> Result<protocol::BundleHeader> {
      if (!keep_replica) return protocol::parse_bundle_header(bytes, limits);
      protocol::BlockFrame scratch;
      return bundle_decoder.decode(bytes, limits, scratch,
                                   [&](protocol::BlockFrame& f) -> Result<void> {
                                     if (decoded == bundled.size()) bundled.emplace_back();
                                     std::swap(bundled[decoded++], f);
                                     return {};
                                   });
    };
    const auto r = read();
    std::lock_guard lock(mutex);
    if (failed) return;
    if (!r) return protocol_failure("undecodable frame bundle: " + r.error().message);
    stats.frame_bytes += bytes.size();
    stats.header_bytes += protocol::kBundleHeaderSize;
    ++stats.bundles;
    if (!keep_replica) {
      stats.frames += r->record_count;
      note_frame_epoch(r->epoch);
      return;
    }
    for (std::size_t i = 0; i < decoded && !failed; ++i) accept_frame(std::move(bundled[i]));
  }

  // Mutex held.
  void note_frame_epoch(std::uint64_t epoch) {
    if (epoch > last_frame_epoch || first_frames.empty()) {
      last_frame_epoch = epoch;
      first_frames.emplace_back(epoch, Clock::now());
      while (first_frames.size() > 65536) first_frames.pop_front();
    }
  }

  // A decoded block frame (only its header without a replica): counted, and staged into the
  // replica. Mutex held.
  void accept_frame(protocol::BlockFrame&& frame) {
    ++stats.frames;
    stats.raw_bytes += frame.header.raw_size;
    if (frame.is_delta()) ++stats.delta_frames;
    note_frame_epoch(frame.header.epoch);
    if (keep_replica && replica) {
      const CommittedRange range{frame.header.first_cell, frame.header.cell_count};
      const std::uint64_t g0 = frame.header.first_cell / 8;
      const bool has_mask = frame.has(protocol::kFieldNeighbourMask);
      std::vector<std::uint64_t> mask;
      if (has_mask) mask = frame.neighbour_mask;
      if (auto st = replica->stage(std::move(frame)); !st) {
        return protocol_failure("block frame not applicable: " + st.error().message);
      } else {
        note_staged(range, g0, mask);
      }
      if (progressive_join && stats.epochs == 0) maybe_commit_partial();
    }
  }

  // During the snapshot (the first batch, onto an empty replica): commits what has come when
  // progressive_first has passed since its first frame or 256 frames have come, and then
  // whenever progressive_first has passed since the previous part and the frames received have
  // at least doubled since it. Mutex held.
  void maybe_commit_partial() {
    // On a fast link thousands of frames come in progressive_first: the first part is due at
    // this many frames already, so that it stays small (its links and upload are quick).
    constexpr std::uint64_t kFirstPartFrames = 256;
    const auto now = Clock::now();
    if (snapshot_frames++ == 0) snapshot_started = now;
    if (now - snapshot_started < progressive_first && snapshot_frames < kFirstPartFrames) return;
    if (frames_at_last_partial > 0 &&
        (now - last_partial < progressive_first || snapshot_frames < 2 * frames_at_last_partial))
      return;
    if (replica->commit_partial() == 0) return;  // the roots' block has not come
    frames_at_last_partial = snapshot_frames;
    last_partial = now;
    ++stats.partial_commits;
    notify_commit(last_frame_epoch, true);
  }

  // The epoch listener, after a commit (partial: a part of the snapshot). A commit of or
  // after a partial one has changed the links of groups the frames did not mark: every group
  // received is passed. Mutex held.
  void notify_commit(std::uint64_t epoch, bool partial) {
    if (epoch_listener) {
      std::vector<std::uint32_t> all_groups;
      std::span<const std::uint32_t> groups = staged_masked_groups;
      if (partial || !replica->changed_cells().empty() || frames_at_last_partial > 0) {
        all_groups = replica->received_groups();
        groups = all_groups;
      }
      EpochCommit c{epoch, *replica, staged_ranges, groups, false};
      c.partial = partial;
      c.changed_cells = replica->changed_cells();
      epoch_listener(c);
    }
    staged_ranges.clear();
    staged_masked_groups.clear();
  }

  // Records what a staged frame carries for the epoch listener (mutex held).
  void note_staged(const CommittedRange& range, std::uint64_t g0,
                   const std::vector<std::uint64_t>& mask) {
    staged_ranges.push_back(range);
    const std::uint64_t groups = range.cell_count / 8;
    for (std::size_t w = 0; w < mask.size() && w * 64 < groups; ++w) {
      std::uint64_t bits = mask[w];
      while (bits) {
        const std::uint64_t i = w * 64 + static_cast<std::uint64_t>(std::countr_zero(bits));
        bits &= bits - 1;
        if (i < groups) staged_masked_groups.push_back(static_cast<std::uint32_t>(g0 + i));
      }
    }
  }

  // What the server's messages are checked against: its canvas (presence cursors) and the
  // largest message this client reads.
  protocol::DecodeOptions decode_options() const {
    protocol::DecodeOptions o;
    o.bounds.edge_m = welcome.geometry.edge_m;
    o.max_bytes = 64u << 20;
    return o;
  }

  void on_text(std::string_view text) {
    auto m = protocol::decode_message(text, decode_options());
    std::lock_guard lock(mutex);
    if (!m) {
      ++stats.decode_failures;
      return;
    }
    if (auto* e = std::get_if<protocol::EpochEnd>(&*m)) {
      if (replica) replica->commit();
      // Epochs between the last batch and this one were coalesced into it (the first batch,
      // the snapshot, follows nothing).
      const std::uint64_t skipped =
          stats.epochs > 0 && e->epoch > applied_epoch + 1 ? e->epoch - applied_epoch - 1 : 0;
      stats.epochs_skipped += skipped;
      stats.behind_batches = skipped > 0 ? stats.behind_batches + 1 : 0;
      applied_epoch = std::max(applied_epoch, e->epoch);
      if (replica) notify_commit(applied_epoch, false);
      frames_at_last_partial = 0;
      stats.applied_epoch = applied_epoch;
      ++stats.epochs;
    } else if (auto* a = std::get_if<protocol::Ack>(&*m)) {
      acks[a->handle] = *a;
      ++stats.acks;
    } else if (auto* p = std::get_if<protocol::PickUpReply>(&*m)) {
      picks[p->request_id] = *p;
    } else if (auto* s = std::get_if<protocol::Stats>(&*m)) {
      last_stats = *s;
    } else if (auto* pu = std::get_if<protocol::PresenceUpdate>(&*m)) {
      ++presence_updates;
      if (pu->gone)
        presence.erase(pu->artist);
      else
        presence[pu->artist] = std::move(*pu);
    } else if (auto* ex = std::get_if<protocol::ExportReply>(&*m)) {
      exports.insert_or_assign(ex->request_id, Result<protocol::ExportReply>(std::move(*ex)));
    } else if (auto* pb = std::get_if<protocol::PlaybackPosition>(&*m)) {
      playbacks.insert_or_assign(pb->request_id, Result<protocol::PlaybackPosition>(*pb));
    } else if (auto* im = std::get_if<protocol::ImportReply>(&*m)) {
      imports.insert_or_assign(im->request_id, Result<protocol::ImportReply>(*im));
    } else if (auto* u = std::get_if<protocol::UndoReply>(&*m)) {
      undos.insert_or_assign(u->request_id, Result<protocol::UndoReply>(*u));
    } else if (auto* er = std::get_if<protocol::ErrorMessage>(&*m)) {
      if (er->in_reply_to == "export" && er->handle)
        exports.insert_or_assign(*er->handle,
                                 Result<protocol::ExportReply>(Error{er->code, er->message}));
      if (er->in_reply_to == "playback_step" && er->handle)
        playbacks.insert_or_assign(
            *er->handle, Result<protocol::PlaybackPosition>(Error{er->code, er->message}));
      if (er->in_reply_to == "import" && er->handle)
        imports.insert_or_assign(*er->handle,
                                 Result<protocol::ImportReply>(Error{er->code, er->message}));
      if ((er->in_reply_to == "undo" || er->in_reply_to == "redo") && er->handle)
        undos.insert_or_assign(*er->handle,
                               Result<protocol::UndoReply>(Error{er->code, er->message}));
      errors.push_back(*er);
      ++stats.errors;
    }
    cv.notify_all();
  }

  void ended(beast::error_code ec) {
    std::lock_guard lock(mutex);
    open = false;
    if (ec == websocket::error::closed)
      close_code = static_cast<int>(with_ws([](auto& w) { return w.reason().code; }));
    cv.notify_all();
  }

  void queue(Out o) {
    net::post(ioc, [self = shared_from_this(), o = std::move(o)]() mutable {
      self->out.push_back(std::move(o));
      self->do_write();
    });
  }

  void do_write() {
    if (writing || out.empty()) return;
    {
      std::lock_guard lock(mutex);
      if (!open) {
        out.clear();
        return;
      }
    }
    writing = true;
    Out& o = out.front();
    auto handler = [self = shared_from_this()](beast::error_code ec, std::size_t) {
      self->writing = false;
      self->out.pop_front();
      if (ec) return;  // the read side reports the end of the connection
      self->do_write();
    };
    with_ws([&](auto& w) {
      w.binary(o.is_binary);
      if (o.is_binary)
        w.async_write(net::buffer(o.binary), handler);
      else
        w.async_write(net::buffer(o.text), handler);
    });
  }

  Result<void> send(const protocol::Message& m) {
    {
      std::lock_guard lock(mutex);
      if (!open) return make_error(Errc::io_error, "connection closed");
    }
    Out o;
    o.text = protocol::encode_message(m);
    queue(std::move(o));
    return {};
  }

  std::uint64_t take_handle() {
    std::lock_guard lock(mutex);
    return next_handle++;
  }
};

}  // namespace deepcanvas::client_core
