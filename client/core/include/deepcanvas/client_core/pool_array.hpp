// PoolArray: the storage of a replica's pools, an array of trivially copyable T with a size, on
// a base::ReservedArray of a fixed capacity, so that its growth costs what is written into it,
// not its size.
//
// Why: a client joining a large canvas grows its pools to the snapshot's index range before the
// first part shows, and a std::vector grows by copying what it holds and writing every new
// element: at 128M cells that was seconds (about 1 s per GB, mostly page faults of the writes)
// before the first picture. A PoolArray reserves its whole capacity (address space only,
// MAP_NORESERVE, as the server's octree does) on its first growth; growing then only moves the
// size: nothing is copied or moved, and new elements read as zero until written (only the pages
// written take memory). So new elements are zero (`resize(n)`), or the value `fill`
// (`resize(n, fill)`, which writes them: use it only where zero cannot stand in).
//
// Contract: not thread-safe (like std::vector). The address never changes once reserved, but
// treat pointers and spans as a std::vector's (invalidated by resize). Copyable (a copy writes
// every element). Growth past capacity() throws std::length_error; no address space for the
// reservation throws std::bad_alloc, as std::vector does.
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstring>
#include <new>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <utility>

#include "deepcanvas/base/reserved_array.hpp"

namespace deepcanvas::client_core {

template <class T>
class PoolArray {
  static_assert(std::is_trivially_copyable_v<T>, "PoolArray holds plain pool words");

 public:
  // Room for up to `capacity` elements; nothing is reserved until the first growth.
  explicit PoolArray(std::size_t capacity = 0) noexcept : capacity_(capacity) {}
  PoolArray(const PoolArray& o) : capacity_(o.capacity_) { *this = o; }
  PoolArray& operator=(const PoolArray& o) {
    if (this == &o) return *this;
    capacity_ = o.capacity_;
    store_ = {};
    size_ = 0;
    resize(o.size_);
    if (o.size_ > 0) std::memcpy(store_.data(), o.store_.data(), o.size_ * sizeof(T));
    return *this;
  }
  PoolArray(PoolArray&& o) noexcept
      : store_(std::move(o.store_)),
        size_(std::exchange(o.size_, 0)),
        capacity_(o.capacity_) {}
  PoolArray& operator=(PoolArray&& o) noexcept {
    store_ = std::move(o.store_);
    size_ = std::exchange(o.size_, 0);
    capacity_ = o.capacity_;
    return *this;
  }

  // New elements read as zero; nothing is written.
  void resize(std::size_t n) {
    if (n > capacity_)
      throw std::length_error("PoolArray: " + std::to_string(n) + " elements past its capacity " +
                              std::to_string(capacity_));
    if (n > 0 && store_.data() == nullptr && !store_.reserve(capacity_)) throw std::bad_alloc();
    if (n < size_) std::memset(store_.data() + n, 0, (size_ - n) * sizeof(T));  // zero again
    size_ = n;
  }
  // New elements are `fill` (written).
  void resize(std::size_t n, const T& fill) {
    const std::size_t old = size_;
    resize(n);
    if (n > old && !is_zero(fill)) std::fill(store_.data() + old, store_.data() + n, fill);
  }

  std::size_t size() const noexcept { return size_; }
  std::size_t capacity() const noexcept { return capacity_; }
  bool empty() const noexcept { return size_ == 0; }
  T* data() noexcept { return store_.data(); }
  const T* data() const noexcept { return store_.data(); }
  T& operator[](std::size_t i) noexcept { return store_[i]; }
  const T& operator[](std::size_t i) const noexcept { return store_[i]; }
  T* begin() noexcept { return store_.data(); }
  T* end() noexcept { return store_.data() + size_; }
  const T* begin() const noexcept { return store_.data(); }
  const T* end() const noexcept { return store_.data() + size_; }

 private:
  static bool is_zero(const T& v) noexcept {
    unsigned char bytes[sizeof(T)];
    std::memcpy(bytes, &v, sizeof(T));
    return std::all_of(bytes, bytes + sizeof(T), [](unsigned char b) { return b == 0; });
  }

  base::ReservedArray<T> store_;
  std::size_t size_ = 0;
  std::size_t capacity_ = 0;
};

}  // namespace deepcanvas::client_core
