// Helpers shared by the CanvasService tests (canvas_service_test.cpp,
// canvas_service_strokes_test.cpp).
#pragma once

#include <gtest/gtest.h>

#include <memory>
#include <mutex>
#include <vector>

#include "deepcanvas/base/log.hpp"
#include "deepcanvas/server_core/canvas_service.hpp"
#include "server_test_util.hpp"

namespace deepcanvas::test {

// A small canvas "c" (small_canvas) with the service's threads running; null (and a test
// failure) if it cannot be made.
inline std::unique_ptr<server_core::CanvasService> make_service() {
  base::set_log_level(base::LogLevel::warn);
  auto s = server_core::CanvasService::create(small_canvas("c"));
  EXPECT_TRUE(s.ok()) << (s ? "" : s.error().message);
  return s ? std::move(*s) : nullptr;
}

// The stroke events a service reports (CanvasServiceConfig::on_stroke_event), in their order.
// Read `events` under `mutex`, or after the service has quiesced.
struct EventLog {
  std::mutex mutex;
  std::vector<server_core::StrokeEvent> events;
  void attach(server_core::CanvasServiceConfig& cfg) {
    cfg.on_stroke_event = [this](const server_core::StrokeEvent& e) {
      std::lock_guard lock(mutex);
      events.push_back(e);
    };
  }
};

// A stroke built here enters the way the network layer's do: made a ValidatedStroke with the
// canvas's rules, then submitted. A stroke that fails the rules is refused with their error.
inline Result<void> submit(server_core::CanvasService& svc, protocol::Stroke stroke,
                           server_core::AckFn done, std::uint64_t artist = 0) {
  auto v = protocol::ValidatedStroke::make(std::move(stroke), svc.stroke_rules());
  if (!v) return std::move(v).error();
  return svc.submit_stroke(std::move(*v), server_core::Clock::now(), std::move(done), artist);
}

}  // namespace deepcanvas::test
