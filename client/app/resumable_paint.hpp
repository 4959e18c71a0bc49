// ResumablePaint: sends a painting's strokes with a client id (hello "client_id") and handles
// 1..N, and survives a broken connection: it reconnects with backoff and resends, in order, the
// strokes it has no ack for, so the painting finishes with each stroke applied once (the server
// answers a stroke it has seen before with its first ack, PROTOCOL.md 3.3.1).
//
// Why resend in order, whole: the server received a prefix of what was sent (one TCP stream),
// so resending every unacknowledged stroke in handle order paints the missing ones in the order
// of a run without a break (the same canvas); a streamed stroke cut by the break was ended by
// the server with the samples it had, so its resend is answered with that stroke's ack.
//
// Errors: an error about a stroke (the server refused it) ends the run; a lost connection is
// retried until `reconnect_s` has passed without one; a refused hello is not retried.
// Threading: one thread (the command's).
#pragma once

#include <chrono>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "deepcanvas/base/result.hpp"
#include "deepcanvas/client_core/client.hpp"
#include "deepcanvas/protocol/messages.hpp"

namespace deepcanvas::client_app {

struct ResumableOptions {
  bool recorded_pace = false;  // stream each stroke at the artist's pace (else whole strokes)
  double ack_timeout_s = 600;  // waiting for the acks after the last stroke was sent
  double reconnect_s = 60;     // give up after this long without a connection (0: never retry)
  bool quiet = false;          // no progress or reconnect lines on stderr
  std::string progress_label;
};

struct PaintOutcome {
  protocol::Ack last_ack;  // the last stroke's
  int reconnects = 0;
  std::size_t resent = 0;  // stroke messages sent again after a reconnect
};

// A client id for one run: 128 random bits, as PROTOCOL.md 3.3.1 asks.
std::string random_client_id();

// Paints `strokes` through connections made with `options` (options.client_id set by the
// caller). `first` is the connection already made (its hello accepted).
Result<PaintOutcome> paint_resumable(std::unique_ptr<client_core::Client> first,
                                     const client_core::ClientOptions& options,
                                     const std::vector<protocol::Stroke>& strokes,
                                     const ResumableOptions& run);

}  // namespace deepcanvas::client_app
