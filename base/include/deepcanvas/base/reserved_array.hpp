// ReservedArray<T>: a fixed-capacity array backed by one anonymous virtual-memory reservation
// (mmap, MAP_NORESERVE). Pages are committed by the kernel on first touch and read as zero
// before that, so an array can reserve its whole capacity up front and "grow" simply by being
// written further: its address never changes, so indices and pointers into it stay valid, and
// growing neither copies nor writes. The server's octree pools and the client's replica pools
// (client_core::PoolArray) both rest on it.
// T must be an implicit-lifetime type for which all-zero bytes are a valid value.
// Contract: not thread-safe; move-only; reserve() reports failure (no address space, e.g. under
// an address-space limit) by returning false, never by throwing.
#pragma once

#include <sys/mman.h>
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <type_traits>
#include <utility>

namespace deepcanvas::base {

inline std::size_t page_size() noexcept {
  static const std::size_t size = static_cast<std::size_t>(::sysconf(_SC_PAGESIZE));
  return size;
}

inline std::size_t round_up_to_page(std::size_t bytes) noexcept {
  const std::size_t p = page_size();
  return (bytes + p - 1) / p * p;
}

template <class T>
class ReservedArray {
  static_assert(std::is_trivially_copyable_v<T>, "ReservedArray holds plain data only");

 public:
  ReservedArray() = default;
  ~ReservedArray() { release(); }
  ReservedArray(const ReservedArray&) = delete;
  ReservedArray& operator=(const ReservedArray&) = delete;
  ReservedArray(ReservedArray&& o) noexcept
      : data_(std::exchange(o.data_, nullptr)),
        count_(std::exchange(o.count_, 0)),
        bytes_(std::exchange(o.bytes_, 0)) {}
  ReservedArray& operator=(ReservedArray&& o) noexcept {
    if (this != &o) {
      release();
      data_ = std::exchange(o.data_, nullptr);
      count_ = std::exchange(o.count_, 0);
      bytes_ = std::exchange(o.bytes_, 0);
    }
    return *this;
  }

  // Reserves room for `count` elements (zero-filled). False when the kernel refuses.
  bool reserve(std::size_t count) noexcept {
    release();
    if (count == 0) count = 1;
    const std::size_t bytes = round_up_to_page(count * sizeof(T));
    void* p = ::mmap(nullptr, bytes, PROT_READ | PROT_WRITE,
                     MAP_PRIVATE | MAP_ANONYMOUS | MAP_NORESERVE, -1, 0);
    if (p == MAP_FAILED) return false;
    // No MADV_HUGEPAGE: transparent huge pages make the uniform build faster but stroke bursts
    // several times slower (a 2 MiB fault may compact memory synchronously, stalling the stroke
    // thread for milliseconds; deepcanvas-bench octree times both), and they commit memory 2 MiB
    // at a time.
    data_ = static_cast<T*>(p);
    count_ = count;
    bytes_ = bytes;
    return true;
  }

  // Gives every page back to the kernel; the array reads as zeros afterwards.
  void discard() noexcept {
    if (data_) ::madvise(data_, bytes_, MADV_DONTNEED);
  }

  T* data() noexcept { return data_; }
  const T* data() const noexcept { return data_; }
  T& operator[](std::size_t i) noexcept { return data_[i]; }
  const T& operator[](std::size_t i) const noexcept { return data_[i]; }
  std::size_t capacity() const noexcept { return count_; }
  std::size_t reserved_bytes() const noexcept { return bytes_; }

 private:
  void release() noexcept {
    if (data_) ::munmap(data_, bytes_);
    data_ = nullptr;
    count_ = 0;
    bytes_ = 0;
  }

  T* data_ = nullptr;
  std::size_t count_ = 0;
  std::size_t bytes_ = 0;
};

}  // namespace deepcanvas::base
