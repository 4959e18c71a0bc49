// TextFrameDeferral<Next>: the stream layer under a server WebSocket that lets the session, not
// Boost.Beast, judge a client's text frames as UTF-8.
//
// Why: Beast checks every text frame for UTF-8 inside its read and, on invalid bytes, fails the
// connection with close code 1007 before the read returns (RFC 6455 8.1). It has no option to
// skip the check, so the session could never tell the client why. Our protocol promises a
// `malformed` error before every close caused by what a client sent (PROTOCOL.md 1).
//
// What: it passes every byte through unchanged except the opcode of a client's text frame,
// which it hands to Beast as binary (so Beast does not check it), and it records each data
// message's real kind in order. The session takes one kind per message it reads
// (take_message_kind), and checks a text message's UTF-8 itself. Only the read direction is
// touched; writes go straight to Next.
//
// The frame parser follows RFC 6455 5.2 on bytes as they arrive, in any split: a header may
// span reads; payloads are skipped by length (masking does not matter: only headers are read).
// Bytes that are not a valid frame are passed on as they are, and Beast fails the connection on
// them as before. Must see every byte from the first frame on: Beast's accept with an already
// parsed request reads nothing before the frames.
//
// Threading: as Next (used on the session's strand only).
#pragma once

#include <array>
#include <boost/asio.hpp>
#include <boost/beast.hpp>
#include <boost/beast/ssl.hpp>
#include <cstdint>
#include <deque>
#include <utility>

namespace deepcanvas::server_net {

// The frame-header state machine, without the stream (unit-testable).
class ClientFrameScanner {
 public:
  enum class MessageKind : std::uint8_t { text, binary };

  // Scans `n` bytes read from the client, in place: a text frame's opcode (1) becomes binary
  // (2); each data frame that begins a message (opcode 1 or 2) records its kind.
  void scan(unsigned char* p, std::size_t n) {
    std::size_t i = 0;
    while (i < n) {
      if (payload_left_ > 0) {
        const std::size_t skip =
            static_cast<std::size_t>(std::min<std::uint64_t>(payload_left_, n - i));
        payload_left_ -= skip;
        i += skip;
        continue;
      }
      if (header_have_ == 0) {
        const unsigned opcode = p[i] & 0x0fu;
        if (opcode == 1) {
          p[i] = static_cast<unsigned char>((p[i] & 0xf0u) | 2u);
          kinds_.push_back(MessageKind::text);
        } else if (opcode == 2) {
          kinds_.push_back(MessageKind::binary);
        }
      }
      header_[header_have_++] = p[i++];
      if (header_have_ >= 2 && header_have_ == header_length()) {
        payload_left_ = payload_length();
        header_have_ = 0;
      }
    }
  }

  // The kind of the oldest message not yet taken; binary when none was recorded (a message
  // Beast assembled from bytes this scanner did not see as a frame start cannot happen, but
  // binary is the kind the session would then have been told by Beast).
  MessageKind take_message_kind() {
    if (kinds_.empty()) return MessageKind::binary;
    const MessageKind k = kinds_.front();
    kinds_.pop_front();
    return k;
  }

 private:
  std::size_t header_length() const {
    const unsigned len7 = header_[1] & 0x7fu;
    const bool masked = (header_[1] & 0x80u) != 0;
    return 2 + (len7 == 126 ? 2 : len7 == 127 ? 8 : 0) + (masked ? 4 : 0);
  }
  std::uint64_t payload_length() const {
    const unsigned len7 = header_[1] & 0x7fu;
    if (len7 < 126) return len7;
    const int bytes = len7 == 126 ? 2 : 8;
    std::uint64_t v = 0;
    for (int k = 0; k < bytes; ++k) v = (v << 8) | header_[2 + k];
    return v;
  }

  std::array<unsigned char, 14> header_{};
  std::size_t header_have_ = 0;
  std::uint64_t payload_left_ = 0;
  std::deque<MessageKind> kinds_;
};

template <class Next>
class TextFrameDeferral {
 public:
  using next_layer_type = Next;
  using executor_type = typename Next::executor_type;

  explicit TextFrameDeferral(Next next) : next_(std::move(next)) {}
  TextFrameDeferral(TextFrameDeferral&&) = default;

  Next& next_layer() noexcept { return next_; }
  const Next& next_layer() const noexcept { return next_; }
  executor_type get_executor() noexcept { return next_.get_executor(); }

  ClientFrameScanner::MessageKind take_message_kind() { return scanner_.take_message_kind(); }

  template <class MutableBuffers, class Token>
  auto async_read_some(const MutableBuffers& buffers, Token&& token) {
    return boost::asio::async_compose<Token, void(boost::beast::error_code, std::size_t)>(
        ReadOp<MutableBuffers>{this, buffers, false}, token, next_);
  }

  template <class ConstBuffers, class Token>
  auto async_write_some(const ConstBuffers& buffers, Token&& token) {
    return next_.async_write_some(buffers, std::forward<Token>(token));
  }

 private:
  template <class MutableBuffers>
  struct ReadOp {
    TextFrameDeferral* self;
    MutableBuffers buffers;
    bool started;

    template <class Self>
    void operator()(Self& op, boost::beast::error_code ec = {}, std::size_t n = 0) {
      if (!started) {
        started = true;
        return self->next_.async_read_some(buffers, std::move(op));
      }
      std::size_t left = n;
      for (auto it = boost::asio::buffer_sequence_begin(buffers);
           left > 0 && it != boost::asio::buffer_sequence_end(buffers); ++it) {
        const boost::asio::mutable_buffer b = *it;
        const std::size_t take = std::min(left, b.size());
        self->scanner_.scan(static_cast<unsigned char*>(b.data()), take);
        left -= take;
      }
      op.complete(ec, n);
    }
  };

  Next next_;
  ClientFrameScanner scanner_;
};

// Closing a WebSocket tears down the layer below: the same as for Next.
template <class Next>
void teardown(boost::beast::role_type role, TextFrameDeferral<Next>& stream,
              boost::beast::error_code& ec) {
  using boost::beast::websocket::teardown;
  teardown(role, stream.next_layer(), ec);
}

template <class Next, class Handler>
void async_teardown(boost::beast::role_type role, TextFrameDeferral<Next>& stream,
                    Handler&& handler) {
  using boost::beast::websocket::async_teardown;
  async_teardown(role, stream.next_layer(), std::forward<Handler>(handler));
}

}  // namespace deepcanvas::server_net
