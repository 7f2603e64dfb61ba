// Replaces the global allocation functions with counting ones, so a test can prove that a code
// path allocates nothing. Include it from exactly one file of a test program (it defines the
// replacement operators, which must exist once per program).
//
// Counters (namespace ecat::test::allocations):
//   total          every allocation in the program, on any thread;
//   counted        allocations on threads that set `count_this_thread`;
//   bus_thread     allocations on the thread that set `is_bus_thread` (a bus's on_thread_start),
//                  while `count_bus_thread` is set.
// The call stack of the first bus-thread allocation is kept: print_first_bus_stack() writes it to
// stderr (library functions by name; the test's own as addresses for addr2line).
#pragma once

#include <atomic>
#include <cstddef>
#include <cstdlib>
#include <new>

#include <execinfo.h>

namespace ecat::test::allocations {

inline thread_local bool count_this_thread = false;
inline thread_local bool is_bus_thread = false;
inline std::atomic<bool> count_bus_thread{false};
inline std::atomic<std::size_t> total{0};
inline std::atomic<std::size_t> counted{0};
inline std::atomic<std::size_t> bus_thread{0};
inline void* first_bus_stack[48];
inline std::atomic<int> first_bus_depth{0};
// backtrace() loads the unwinder (which allocates) on its first call: done once at start-up.
inline const int backtrace_primed = [] {
  void* frame[1];
  return backtrace(frame, 1);
}();

inline void print_first_bus_stack() {
  const int depth = first_bus_depth.load();
  if (depth > 0) backtrace_symbols_fd(first_bus_stack, depth, 2);
}

// noinline: once inlined, GCC pairs our malloc/free with new/delete expressions at call sites
// and reports a mismatch that is not there.
[[gnu::noinline]] inline void* allocate(std::size_t size, std::size_t align = 0) noexcept {
  total.fetch_add(1, std::memory_order_relaxed);
  if (count_this_thread) counted.fetch_add(1, std::memory_order_relaxed);
  if (is_bus_thread && count_bus_thread.load(std::memory_order_relaxed)) {
    if (bus_thread.fetch_add(1, std::memory_order_relaxed) == 0) {
      first_bus_depth.store(backtrace(first_bus_stack, 48));
    }
  }
  if (align == 0) return std::malloc(size == 0 ? 1 : size);
  const std::size_t rounded = (size + align - 1) / align * align;
  return std::aligned_alloc(align, rounded == 0 ? align : rounded);
}
[[gnu::noinline]] inline void release(void* p) noexcept {
  std::free(p);
}

inline void* allocate_or_throw(std::size_t size, std::size_t align = 0) {
  if (void* p = allocate(size, align)) return p;
  throw std::bad_alloc();
}

}  // namespace ecat::test::allocations

[[gnu::noinline]] void* operator new(std::size_t size) {
  return ecat::test::allocations::allocate_or_throw(size);
}
[[gnu::noinline]] void* operator new[](std::size_t size) {
  return ecat::test::allocations::allocate_or_throw(size);
}
[[gnu::noinline]] void* operator new(std::size_t size, const std::nothrow_t&) noexcept {
  return ecat::test::allocations::allocate(size);
}
[[gnu::noinline]] void* operator new[](std::size_t size, const std::nothrow_t&) noexcept {
  return ecat::test::allocations::allocate(size);
}
[[gnu::noinline]] void* operator new(std::size_t size, std::align_val_t align) {
  return ecat::test::allocations::allocate_or_throw(size, static_cast<std::size_t>(align));
}
[[gnu::noinline]] void* operator new[](std::size_t size, std::align_val_t align) {
  return ecat::test::allocations::allocate_or_throw(size, static_cast<std::size_t>(align));
}
[[gnu::noinline]] void operator delete(void* p) noexcept {
  ecat::test::allocations::release(p);
}
[[gnu::noinline]] void operator delete[](void* p) noexcept {
  ecat::test::allocations::release(p);
}
[[gnu::noinline]] void operator delete(void* p, std::size_t) noexcept {
  ecat::test::allocations::release(p);
}
[[gnu::noinline]] void operator delete[](void* p, std::size_t) noexcept {
  ecat::test::allocations::release(p);
}
[[gnu::noinline]] void operator delete(void* p, const std::nothrow_t&) noexcept {
  ecat::test::allocations::release(p);
}
[[gnu::noinline]] void operator delete[](void* p, const std::nothrow_t&) noexcept {
  ecat::test::allocations::release(p);
}
[[gnu::noinline]] void operator delete(void* p, std::align_val_t) noexcept {
  ecat::test::allocations::release(p);
}
[[gnu::noinline]] void operator delete[](void* p, std::align_val_t) noexcept {
  ecat::test::allocations::release(p);
}
[[gnu::noinline]] void operator delete(void* p, std::size_t, std::align_val_t) noexcept {
  ecat::test::allocations::release(p);
}
[[gnu::noinline]] void operator delete[](void* p, std::size_t, std::align_val_t) noexcept {
  ecat::test::allocations::release(p);
}
