// PoolArray: the storage of a replica's pools, an array of trivially copyable T whose growth costs
// what is written into it, not its size.
//
// Why: a client joining a large canvas grows its pools to the snapshot's index range before the
// first part shows, and a std::vector grows by copying what it holds and writing every new
// element: at 128M cells that was seconds (about 1 s per GB, mostly page faults of the writes)
// before the first picture. A PoolArray is an anonymous private mapping grown with mremap: the
// kernel moves the pages without copying them, and the new range reads as zero until written
// (only the pages written take memory). So new elements are zero (`resize(n)`), or the value
// `fill` (`resize(n, fill)`, which writes them: use it only where zero cannot stand in).
//
// Contract: not thread-safe (like std::vector); pointers and spans into it are invalidated by a
// resize that grows it (the mapping may move). Copyable (a copy writes every element).
// Allocation failure (no address space or memory) throws std::bad_alloc, as std::vector does.
#pragma once

#include <sys/mman.h>

#include <algorithm>
#include <cstddef>
#include <cstring>
#include <new>
#include <type_traits>
#include <utility>

namespace deepcanvas::client_core {

template <class T>
class PoolArray {
  static_assert(std::is_trivially_copyable_v<T>, "PoolArray holds plain pool words");

 public:
  PoolArray() = default;
  PoolArray(const PoolArray& o) { *this = o; }
  PoolArray& operator=(const PoolArray& o) {
    if (this == &o) return *this;
    clear();
    if (o.size_ > 0) {
      grow_mapping(o.size_);
      std::memcpy(data_, o.data_, o.size_ * sizeof(T));
      size_ = o.size_;
    }
    return *this;
  }
  PoolArray(PoolArray&& o) noexcept { swap(o); }
  PoolArray& operator=(PoolArray&& o) noexcept {
    PoolArray tmp(std::move(o));
    swap(tmp);
    return *this;
  }
  ~PoolArray() { clear(); }

  // New elements read as zero; nothing is written.
  void resize(std::size_t n) {
    if (n > size_) grow_mapping(n);
    else if (n < size_) std::memset(data_ + n, 0, (size_ - n) * sizeof(T));  // zero again
    size_ = n;
  }
  // New elements are `fill` (written).
  void resize(std::size_t n, const T& fill) {
    const std::size_t old = size_;
    resize(n);
    if (n > old && !is_zero(fill)) std::fill(data_ + old, data_ + n, fill);
  }

  std::size_t size() const noexcept { return size_; }
  bool empty() const noexcept { return size_ == 0; }
  T* data() noexcept { return data_; }
  const T* data() const noexcept { return data_; }
  T& operator[](std::size_t i) noexcept { return data_[i]; }
  const T& operator[](std::size_t i) const noexcept { return data_[i]; }
  T* begin() noexcept { return data_; }
  T* end() noexcept { return data_ + size_; }
  const T* begin() const noexcept { return data_; }
  const T* end() const noexcept { return data_ + size_; }

  void swap(PoolArray& o) noexcept {
    std::swap(data_, o.data_);
    std::swap(size_, o.size_);
    std::swap(mapped_, o.mapped_);
  }

 private:
  static bool is_zero(const T& v) noexcept {
    unsigned char bytes[sizeof(T)];
    std::memcpy(bytes, &v, sizeof(T));
    return std::all_of(bytes, bytes + sizeof(T), [](unsigned char b) { return b == 0; });
  }
  static std::size_t page_round(std::size_t bytes) {
    constexpr std::size_t kPage = 4096;  // a multiple of the page size on every Linux target
    return (bytes + kPage - 1) / kPage * kPage;
  }
  // Maps room for at least n elements (geometric, like std::vector, so appends stay amortised
  // O(1) in system calls); the bytes past size_ are zero.
  void grow_mapping(std::size_t n) {
    const std::size_t want = page_round(n * sizeof(T));
    if (want <= mapped_) return;
    const std::size_t bytes = std::max(want, page_round(mapped_ + mapped_ / 2));
#if defined(__SANITIZE_THREAD__)
    // ThreadSanitizer does not follow mremap (the moved range keeps the shadow of whatever was
    // mapped there before, and reports races with it): map anew and copy instead.
    void* p = ::mmap(nullptr, bytes, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
    if (p == MAP_FAILED) throw std::bad_alloc();
    if (mapped_ != 0) {
      std::memcpy(p, data_, size_ * sizeof(T));
      ::munmap(data_, mapped_);
    }
#else
    void* p = mapped_ == 0
                  ? ::mmap(nullptr, bytes, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS,
                           -1, 0)
                  : ::mremap(data_, mapped_, bytes, MREMAP_MAYMOVE);
    if (p == MAP_FAILED) throw std::bad_alloc();
#endif
    data_ = static_cast<T*>(p);
    mapped_ = bytes;
  }
  void clear() noexcept {
    if (data_) ::munmap(data_, mapped_);
    data_ = nullptr;
    size_ = 0;
    mapped_ = 0;
  }

  T* data_ = nullptr;
  std::size_t size_ = 0;
  std::size_t mapped_ = 0;  // bytes
};

}  // namespace deepcanvas::client_core
