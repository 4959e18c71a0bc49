// Result<T>: the error model of every core layer (protocol, server_core, client_core).
// Core code never throws for expected failures (bad input, full pools, refused operations);
// it returns a Result carrying a stable error code and a human-readable message.
#pragma once

#include <cassert>
#include <string>
#include <string_view>
#include <utility>
#include <variant>

namespace deepcanvas {

// Stable error codes. They cross the wire (protocol errors carry them by name), so never renumber.
enum class Errc : int {
  ok = 0,
  invalid_argument = 1,   // a value outside its allowed range (NaN, out of canvas, bad size)
  malformed = 2,          // bytes that do not decode (truncated, bad magic, bad checksum)
  unsupported = 3,        // a version or feature this build does not speak
  out_of_memory = 4,      // a pool reached its configured capacity
  refused = 5,            // a legal request the structure declines (e.g. unbalancing coarsen)
  not_found = 6,          // no such cell, canvas, file
  limit_exceeded = 7,     // a configured limit (frame size, rate, samples per stroke)
  unauthorized = 8,       // missing or wrong token, or a role that may not do this
  io_error = 9,           // the operating system refused a read or write
  internal = 10,          // a broken invariant: a bug, never the caller's fault
};

std::string_view errc_name(Errc code) noexcept;

struct Error {
  Errc code = Errc::internal;
  std::string message;
};

template <class T>
class [[nodiscard]] Result {
 public:
  Result(T value) : v_(std::in_place_index<0>, std::move(value)) {}  // NOLINT: implicit by design
  Result(Error error) : v_(std::in_place_index<1>, std::move(error)) {}  // NOLINT

  bool ok() const noexcept { return v_.index() == 0; }
  explicit operator bool() const noexcept { return ok(); }

  T& value() & { assert(ok()); return std::get<0>(v_); }
  const T& value() const& { assert(ok()); return std::get<0>(v_); }
  T&& value() && { assert(ok()); return std::get<0>(std::move(v_)); }
  T* operator->() { return &value(); }
  const T* operator->() const { return &value(); }
  T& operator*() & { return value(); }
  const T& operator*() const& { return value(); }

  const Error& error() const& { assert(!ok()); return std::get<1>(v_); }
  Error&& error() && { assert(!ok()); return std::get<1>(std::move(v_)); }

 private:
  std::variant<T, Error> v_;
};

template <>
class [[nodiscard]] Result<void> {
 public:
  Result() = default;
  Result(Error error) : error_(std::move(error)), ok_(false) {}  // NOLINT

  bool ok() const noexcept { return ok_; }
  explicit operator bool() const noexcept { return ok_; }
  const Error& error() const& { assert(!ok_); return error_; }
  Error&& error() && { assert(!ok_); return std::move(error_); }

 private:
  Error error_{};
  bool ok_ = true;
};

inline Error make_error(Errc code, std::string message) { return Error{code, std::move(message)}; }

}  // namespace deepcanvas
