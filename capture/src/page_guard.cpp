// SPDX-License-Identifier: Apache-2.0
#include "page_guard.h"

#include "clastrace/capture/uncached_copy.h"

#include <algorithm>
#include <cerrno>
#include <csignal>
#include <cstring>
#include <ctime>
#include <functional>
#include <new>
#include <vector>

#include <sys/mman.h>
#include <sys/syscall.h>
#include <unistd.h>

#if defined(__x86_64__) || defined(__i386__)
#include <immintrin.h>
#endif

namespace clastrace::capture {
namespace {

// The table's entries, one before-image slot each, mapped without reserve: only the slots of
// pages written while protected take memory. Past half full (64 Ki distinct pages, 256 MiB of
// 4 KiB pages) the table refuses new pages (short probes), and the watch hashes those ranges.
constexpr size_t kTableEntries = size_t(1) << 17;

// A fault on a page the guard holds but does not protect is a write that raced with the page
// being made writable, and its retry goes through; one that keeps coming back this many times is
// not the guard's (the application protected the page itself) and goes to the next handler.
constexpr uint32_t kMaxStrayFaults = 1024;

// How many unwatches a page written while resting is made writable at, rather than left resting,
// after its first such write; each later one doubles it, up to kMostHotUnwatches. A page the host
// rewrites every frame then takes a fault (a signal and an mprotect on the writing thread) about
// log2(frames) times, not once in every kHotUnwatches + 1 frames (891 faults in 240 frames of the
// capture bench on the device, ~30 us each), and costs one page of an mprotect run in the others;
// a page written once rests again after kHotUnwatches.
constexpr uint32_t kHotUnwatches = 8;
constexpr uint32_t kMostHotUnwatches = 1024;

std::atomic<PageGuard*> the_guard{nullptr};
struct sigaction previous_action {};  // the handler the guard passes other faults to

void cpu_relax() {
#if defined(__x86_64__) || defined(__i386__)
    _mm_pause();
#endif
}

void pass_on(int signal, siginfo_t* info, void* context) {
    const struct sigaction& p = previous_action;
    if (p.sa_flags & SA_SIGINFO) {
        if (p.sa_sigaction) p.sa_sigaction(signal, info, context);
        return;
    }
    if (p.sa_handler == SIG_DFL || p.sa_handler == SIG_IGN) {
        // The faulting instruction runs again and gets the default action (a core dump).
        struct sigaction fallback {};
        fallback.sa_handler = SIG_DFL;
        sigaction(signal, &fallback, nullptr);
        return;
    }
    p.sa_handler(signal);
}

void on_fault(int signal, siginfo_t* info, void* context) {
    const int saved_errno = errno;
    PageGuard* guard = the_guard.load(std::memory_order_acquire);
    const auto address = reinterpret_cast<uintptr_t>(info ? info->si_addr : nullptr);
    const bool ours = guard && info && info->si_code == SEGV_ACCERR && guard->take_fault(address);
    if (!ours && guard) guard->end_failed_probe(address);
    errno = saved_errno;
    if (!ours) pass_on(signal, info, context);
}

struct sigaction guard_action() {
    struct sigaction action {};
    action.sa_sigaction = on_fault;
    action.sa_flags = SA_SIGINFO | SA_RESTART | SA_ONSTACK;
    sigemptyset(&action.sa_mask);
    return action;
}

// clock_gettime is async-signal-safe, so the handler times its copies with it too.
uint64_t clock_ns(clockid_t clock) {
    timespec t{};
    clock_gettime(clock, &t);
    return uint64_t(t.tv_sec) * 1000000000ull + uint64_t(t.tv_nsec);
}
uint64_t monotonic_ns() { return clock_ns(CLOCK_MONOTONIC); }
// The calling thread's CPU time: against the wall time of mprotect, what it spent waiting (the
// other CPUs' acknowledgements of its TLB shootdown, a lock of the kernel's).
uint64_t thread_cpu_time_ns() { return clock_ns(CLOCK_THREAD_CPUTIME_ID); }

size_t slot_index_hash(uintptr_t page, size_t page_size) {
    return size_t(((page / page_size) * 0x9E3779B97F4A7C15ull) >> 47) & (kTableEntries - 1);
}

// Sorted, each page once; a kept walk's groups come so already, and are not sorted again.
void sort_once(std::vector<uintptr_t>& pages) {
    if (std::adjacent_find(pages.begin(), pages.end(), std::greater_equal<>()) == pages.end())
        return;
    std::sort(pages.begin(), pages.end());
    pages.erase(std::unique(pages.begin(), pages.end()), pages.end());
}

}  // namespace

PageGuard::PageGuard(size_t page_size, Entry* table, uint8_t* slots)
    : page_size_(page_size), table_(table), slots_(slots) {}

PageGuard* PageGuard::instance() {
    static PageGuard* const kGuard = []() -> PageGuard* {
        const long page_size = sysconf(_SC_PAGESIZE);
        if (page_size <= 0) return nullptr;
        void* table = mmap(nullptr, kTableEntries * sizeof(Entry), PROT_READ | PROT_WRITE,
                           MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
        if (table == MAP_FAILED) return nullptr;
        void* slots = mmap(nullptr, kTableEntries * size_t(page_size), PROT_READ | PROT_WRITE,
                           MAP_PRIVATE | MAP_ANONYMOUS | MAP_NORESERVE, -1, 0);
        if (slots == MAP_FAILED) {
            munmap(table, kTableEntries * sizeof(Entry));
            return nullptr;
        }
        auto* entries = static_cast<Entry*>(table);
        for (size_t i = 0; i < kTableEntries; ++i) new (&entries[i]) Entry;
        // The copy's one-time CPU check runs here, not first inside the handler.
        uint8_t warm[256] = {};
        copy_from_uncached(static_cast<uint8_t*>(slots), warm, sizeof warm);
        auto* guard = new PageGuard(size_t(page_size), entries, static_cast<uint8_t*>(slots));
        struct sigaction action = guard_action();
        if (sigaction(SIGSEGV, &action, &previous_action) != 0) return nullptr;  // (kept mapped)
        the_guard.store(guard, std::memory_order_release);
        return guard;
    }();
    return kGuard;
}

void PageGuard::keep_handler_first() {
    struct sigaction current {};
    if (sigaction(SIGSEGV, nullptr, &current) != 0) return;
    if ((current.sa_flags & SA_SIGINFO) && current.sa_sigaction == on_fault) return;
    previous_action = current;
    struct sigaction action = guard_action();
    sigaction(SIGSEGV, &action, nullptr);
}

PageGuard::Entry* PageGuard::find(uintptr_t page) const {
    for (size_t i = 0, at = slot_index_hash(page, page_size_); i < kTableEntries;
         ++i, at = (at + 1) & (kTableEntries - 1)) {
        const uintptr_t held = table_[at].page.load(std::memory_order_acquire);
        if (held == page) return &table_[at];
        if (held == 0) return nullptr;
    }
    return nullptr;
}

PageGuard::Entry* PageGuard::find_or_add(uintptr_t page) {
    size_t at = slot_index_hash(page, page_size_);
    for (size_t i = 0; i < kTableEntries; ++i, at = (at + 1) & (kTableEntries - 1)) {
        const uintptr_t held = table_[at].page.load(std::memory_order_relaxed);
        if (held == page) return &table_[at];
        if (held == 0) break;
    }
    if (used_ >= kTableEntries / 2) return nullptr;
    ++used_;
    table_[at].page.store(page, std::memory_order_release);
    return &table_[at];
}

uint8_t* PageGuard::slot_of(const Entry* e) const {
    return slots_ + size_t(e - table_) * page_size_;
}

bool PageGuard::protect_runs(const uintptr_t* pages, size_t count, int protection) {
    if (count == 0) return true;
    const bool writable = protection & PROT_WRITE;
    const uint64_t start = monotonic_ns(), start_cpu = thread_cpu_time_ns();
    uint64_t calls = 0, done = 0;
    bool ok = true;
    for (size_t i = 0; i < count;) {
        size_t run = 1;
        while (i + run < count && pages[i + run] == pages[i] + run * page_size_) ++run;
        ++calls;
        if (mprotect(reinterpret_cast<void*>(pages[i]), run * page_size_, protection) != 0) {
            ok = false;
            break;
        }
        done += run;
        i += run;
    }
    const uint64_t took = monotonic_ns() - start, took_cpu = thread_cpu_time_ns() - start_cpu;
    (writable ? unprotect_calls_ : protect_calls_).fetch_add(calls, std::memory_order_relaxed);
    (writable ? unprotected_pages_ : protected_pages_).fetch_add(done, std::memory_order_relaxed);
    (writable ? unprotect_ns_ : protect_ns_).fetch_add(took, std::memory_order_relaxed);
    (writable ? unprotect_cpu_ns_ : protect_cpu_ns_).fetch_add(took_cpu, std::memory_order_relaxed);
    return ok;
}

bool PageGuard::watch(std::vector<uintptr_t> pages, bool uncached) {
    sort_once(pages);
    std::lock_guard lock(mutex_);
    keep_handler_first();
    // Reserved whole: a frame loop's watch lists tens of pages (a vector grown page by page
    // allocates again at each doubling).
    std::vector<uintptr_t> to_protect, adopted;
    std::vector<Entry*> all, entries, protecting;
    for (auto* v : {&to_protect, &adopted}) v->reserve(pages.size());
    for (auto* v : {&all, &entries, &protecting}) v->reserve(pages.size());
    for (uintptr_t page : pages) {
        Entry* e = find_or_add(page);
        if (!e) return false;
        all.push_back(e);
        if (e->watchers) {
            const uint32_t state = e->state.load(std::memory_order_acquire);
            if (state == kWritten || state == kCapturing) return false;
            continue;  // protected already
        }
        entries.push_back(e);
    }
    for (Entry* e : entries) {
        const uintptr_t page = e->page.load(std::memory_order_relaxed);
        e->uncached = uncached;
        // A resting page is read-only and unwritten since: adopted as it is. One the handler
        // took meanwhile is writable again (free) and protected afresh below.
        uint32_t resting = kResting;
        if (e->state.compare_exchange_strong(resting, kArmed, std::memory_order_acq_rel)) {
            adopted.push_back(page);
            continue;
        }
        wait_while_capturing(e);
        // Armed before the page turns read-only: a write in between is one the page held already.
        e->stray_faults.store(0, std::memory_order_relaxed);
        e->state.store(kArmed, std::memory_order_release);
        to_protect.push_back(page);
        protecting.push_back(e);
    }
    if (!protect_runs(to_protect.data(), to_protect.size(), PROT_READ)) {
        release(to_protect);
        for (uintptr_t page : adopted) rest(find(page), page, nullptr);
        refused_.fetch_add(1, std::memory_order_relaxed);
        return false;
    }
    for (Entry* e : protecting)
        if (!e->listed) {
            e->listed = true;
            watched_ever_.insert(e->page.load(std::memory_order_relaxed));
        }
    for (Entry* e : all) ++e->watchers;
    return true;
}

void PageGuard::unwatch(std::vector<uintptr_t> pages) {
    sort_once(pages);
    std::lock_guard lock(mutex_);
    std::vector<uintptr_t> hot;
    hot.reserve(pages.size());
    for (uintptr_t page : pages) {
        Entry* e = find(page);
        if (!e || e->watchers == 0 || --e->watchers > 0) continue;
        rest(e, page, &hot);
    }
    release(hot);  // sorted: pages came sorted
}

void PageGuard::rest(Entry* e, uintptr_t page, std::vector<uintptr_t>* to_release) {
    const uint32_t hot = e->hot.load(std::memory_order_relaxed);
    const bool rests = resting_.load(std::memory_order_relaxed);
    if (to_release && (hot > 0 || !rests) && e->state.load(std::memory_order_acquire) == kArmed) {
        if (hot > 0) e->hot.store(hot - 1, std::memory_order_relaxed);
        to_release->push_back(page);
        return;
    }
    uint32_t armed = kArmed;
    if (e->state.compare_exchange_strong(armed, kResting, std::memory_order_acq_rel)) return;
    // Written (or being written): the handler made it writable; its before-image has no reader.
    wait_while_capturing(e);
    e->state.store(kFree, std::memory_order_release);
}

void PageGuard::forget_memory(uintptr_t begin, size_t size) {
    std::lock_guard lock(mutex_);
    std::vector<uintptr_t> writable;
    for (auto it = watched_ever_.lower_bound(begin);
         it != watched_ever_.end() && *it < begin + size;) {
        Entry* e = find(*it);
        uint32_t resting = kResting;
        // Claimed from the handler as it would claim it; a page it took is writable already.
        if (e && e->state.compare_exchange_strong(resting, kCapturing, std::memory_order_acq_rel))
            writable.push_back(*it);
        else if (e)
            wait_while_capturing(e);
        if (e) {  // other memory may come here next
            e->listed = false;
            e->hot.store(0, std::memory_order_relaxed);
            e->hot_span.store(0, std::memory_order_relaxed);
        }
        it = watched_ever_.erase(it);
    }
    protect_runs(writable.data(), writable.size(), PROT_READ | PROT_WRITE);
    for (uintptr_t page : writable) find(page)->state.store(kFree, std::memory_order_release);
}

void PageGuard::release(const std::vector<uintptr_t>& pages) {
    // Writable first, then free: a fault taken meanwhile still finds the page armed and captures
    // it (harmless), and one that finds it free retries a write that now goes through.
    protect_runs(pages.data(), pages.size(), PROT_READ | PROT_WRITE);
    for (uintptr_t page : pages) {
        Entry* e = find(page);
        if (!e) continue;
        wait_while_capturing(e);
        e->state.store(kFree, std::memory_order_release);
    }
}

bool PageGuard::probe(uintptr_t page) {
    std::lock_guard lock(mutex_);
    keep_handler_first();
    const Entry* held = find(page);
    if (held && (held->watchers || held->listed)) return true;  // guarded already
    Entry* e = find_or_add(page);
    if (!e || e->state.load() != kFree) return false;
    e->uncached = true;
    e->stray_faults.store(0);
    e->state.store(kArmed, std::memory_order_release);
    if (!protect_runs(&page, 1, PROT_READ)) {
        release({page});
        refused_.fetch_add(1, std::memory_order_relaxed);
        return false;
    }
    probing_thread_.store(syscall(SYS_gettid));
    probing_page_.store(page);
    volatile bool wrote = false;
    if (sigsetjmp(probe_return_, 1) == 0) {
        __atomic_fetch_add(reinterpret_cast<volatile uint8_t*>(page), 0, __ATOMIC_SEQ_CST);
        wrote = true;
    }
    probing_page_.store(0);
    release({page});
    if (!wrote) refused_.fetch_add(1, std::memory_order_relaxed);
    return wrote;
}

void PageGuard::end_failed_probe(uintptr_t address) {
    const uintptr_t page = address & ~uintptr_t(page_size_ - 1);
    if (page != 0 && page == probing_page_.load() && probing_thread_.load() == syscall(SYS_gettid))
        siglongjmp(probe_return_, 1);
}

const uint8_t* PageGuard::before_image(uintptr_t page) const {
    const Entry* e = find(page);
    if (!e || e->state.load(std::memory_order_acquire) != kWritten) return nullptr;
    return slot_of(e);
}

PageGuard::Counts PageGuard::counts() const {
    Counts c;
    c.faults = faults_.load(std::memory_order_relaxed);
    c.refused = refused_.load(std::memory_order_relaxed);
    c.resting_faults = resting_faults_.load(std::memory_order_relaxed);
    c.protect_calls = protect_calls_.load(std::memory_order_relaxed);
    c.protected_pages = protected_pages_.load(std::memory_order_relaxed);
    c.protect_ns = protect_ns_.load(std::memory_order_relaxed);
    c.unprotect_calls = unprotect_calls_.load(std::memory_order_relaxed);
    c.unprotected_pages = unprotected_pages_.load(std::memory_order_relaxed);
    c.unprotect_ns = unprotect_ns_.load(std::memory_order_relaxed);
    c.protect_cpu_ns = protect_cpu_ns_.load(std::memory_order_relaxed);
    c.unprotect_cpu_ns = unprotect_cpu_ns_.load(std::memory_order_relaxed);
    c.before_image_ns = before_image_ns_.load(std::memory_order_relaxed);
    c.resting_fault_ns = resting_fault_ns_.load(std::memory_order_relaxed);
    return c;
}

bool PageGuard::take_fault(uintptr_t address) {
    Entry* e = find(address & ~uintptr_t(page_size_ - 1));
    if (!e) return false;
    for (;;) {
        uint32_t state = e->state.load(std::memory_order_acquire);
        if (state == kCapturing) {  // another thread's write to the page: wait for its copy
            cpu_relax();
            continue;
        }
        if (state == kResting) {
            if (!e->state.compare_exchange_weak(state, kCapturing, std::memory_order_acq_rel))
                continue;
            return take_resting_fault(e);
        }
        if (state != kArmed) {
            if (e->page.load() == probing_page_.load()) return false;  // end_failed_probe's
            return e->stray_faults.fetch_add(1, std::memory_order_relaxed) < kMaxStrayFaults;
        }
        if (!e->state.compare_exchange_weak(state, kCapturing, std::memory_order_acq_rel)) continue;
        const uint64_t start = monotonic_ns();
        const auto* page = reinterpret_cast<const uint8_t*>(e->page.load());
        if (e->uncached)
            copy_from_uncached(slot_of(e), page, page_size_);
        else
            std::memcpy(slot_of(e), page, page_size_);
        if (mprotect(const_cast<uint8_t*>(page), page_size_, PROT_READ | PROT_WRITE) != 0) {
            e->state.store(kArmed, std::memory_order_release);
            return false;
        }
        e->state.store(kWritten, std::memory_order_release);
        if (e->page.load() != probing_page_.load()) faults_.fetch_add(1, std::memory_order_relaxed);
        before_image_ns_.fetch_add(monotonic_ns() - start, std::memory_order_relaxed);
        return true;
    }
}

void PageGuard::wait_while_capturing(const Entry* e) {
    while (e->state.load(std::memory_order_acquire) == kCapturing) cpu_relax();
}

bool PageGuard::take_resting_fault(Entry* e) {
    const uint64_t start = monotonic_ns();
    auto* page = reinterpret_cast<void*>(e->page.load());
    if (mprotect(page, page_size_, PROT_READ | PROT_WRITE) != 0) {
        e->state.store(kResting, std::memory_order_release);
        return false;
    }
    const uint32_t span = std::max(e->hot_span.load(std::memory_order_relaxed), kHotUnwatches);
    e->hot.store(span, std::memory_order_relaxed);
    e->hot_span.store(std::min(span * 2, kMostHotUnwatches), std::memory_order_relaxed);
    e->state.store(kFree, std::memory_order_release);
    resting_faults_.fetch_add(1, std::memory_order_relaxed);
    resting_fault_ns_.fetch_add(monotonic_ns() - start, std::memory_order_relaxed);
    return true;
}

}  // namespace clastrace::capture
