// SPDX-License-Identifier: Apache-2.0
// The test program's operator new: while a FailingAllocations lives, big allocations off the
// thread that made it throw, as they would on a machine out of memory. Everything else is
// malloc's, so the sanitizers and valgrind still see every block. Under valgrind give
// --soname-synonyms=somalloc=nouserintercepts, or its operator new replaces this one and no
// allocation fails (the tests say so).
#include "failing_source.h"

#include <cstdlib>
#include <new>

namespace {

std::atomic<bool> armed{false};
std::atomic<size_t> fail_from_bytes{0};
std::atomic<uint32_t> failures{0};
std::thread::id spared;  // written while unarmed only

void* allocate(size_t n) {
    if (armed.load(std::memory_order_acquire) && n >= fail_from_bytes.load() &&
        std::this_thread::get_id() != spared) {
        ++failures;
        throw std::bad_alloc();
    }
    if (void* p = std::malloc(n ? n : 1)) return p;
    throw std::bad_alloc();
}

}  // namespace

void* operator new(size_t n) { return allocate(n); }
void* operator new[](size_t n) { return allocate(n); }
void operator delete(void* p) noexcept { std::free(p); }
void operator delete[](void* p) noexcept { std::free(p); }
void operator delete(void* p, size_t) noexcept { std::free(p); }
void operator delete[](void* p, size_t) noexcept { std::free(p); }

namespace clastrace::traces::testing {

FailingAllocations::FailingAllocations(size_t min_bytes) {
    spared = std::this_thread::get_id();
    fail_from_bytes = min_bytes;
    failures = 0;
    armed.store(true, std::memory_order_release);
}

FailingAllocations::~FailingAllocations() { armed.store(false, std::memory_order_release); }

uint32_t FailingAllocations::failed() const { return failures.load(); }

}  // namespace clastrace::traces::testing
