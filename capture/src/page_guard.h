// SPDX-License-Identifier: Apache-2.0
// Write-protected pages of the layer's mappings, so the host-write watch (host_write_watch.h)
// learns which pages the host wrote between a submission and its wait without reading mapped
// memory, which is uncached (write-combined) on a real GPU. A watched page is made read-only; the
// first write to it faults, and the process-wide SIGSEGV handler copies the page as it was (its
// before-image), makes it writable again and returns, so the write proceeds. Faults on pages the
// guard does not hold go to the handler installed before it (or the default action).
//
// Protection outlives the watchers: a page whose last watcher goes while it was not written stays
// read-only ("resting"), so the next submission that watches it adopts it without an mprotect,
// and a frame loop resubmitting over the same buffers re-protects only the pages written since
// (capture/README.md, "Host writes"). A write to a resting page faults once, and the handler
// only makes the page writable again (nobody needs its before-image). A page written while
// resting is "hot" for its next unwatches (8 after its first such write, twice as many after each
// later one): made writable then, in runs of pages, rather than left to fault one page at a time
// (a frame loop rewriting its vertices after each wait would otherwise pay a fault per page per
// frame). Memory going away (vkFreeMemory) must be forgotten first (forget_memory), or a later
// mapping at its addresses would be taken for protected.
//
// The handler is async-signal-safe: it looks pages up in a fixed open-addressing table and copies
// into fixed slots, both mapped once when the guard starts, and takes no lock. Entries are only
// ever added (under the guard's mutex); a page keeps its entry after its watchers are gone.
#pragma once

#include <atomic>
#include <csetjmp>
#include <cstddef>
#include <cstdint>
#include <mutex>
#include <set>
#include <vector>

namespace clastrace::capture {

class PageGuard {
public:
    // The process's guard; installs the handler on first use. Null when the process cannot have
    // one (the table or the slots could not be mapped, or sigaction failed).
    static PageGuard* instance();

    size_t page_size() const { return page_size_; }

    // Adds a watcher to each page in `pages` (page-aligned, any order; a page listed twice gets
    // one): pages that had none become read-only (resting ones are already), their bytes now the
    // reference. False, with nothing added, when a page was written since it was protected (its
    // reference is gone until its watchers are), the table is full or mprotect refused.
    // `uncached`: the memory is write-combined, so the handler copies the page with streaming
    // loads. Each run of consecutive pages not already read-only costs one mprotect.
    bool watch(std::vector<uintptr_t> pages, bool uncached);
    // Drops a watcher from each page listed (once per page, as watch() added it). A page left
    // without one rests read-only if it was not written (no mprotect), is plain writable memory
    // again if it was (its fault made it writable), and is made writable if it is hot.
    void unwatch(std::vector<uintptr_t> pages);
    // The memory [begin, begin + size) is going away (unmapped, freed): its resting pages become
    // writable and the guard forgets them. Its pages must have no watchers left.
    void forget_memory(uintptr_t begin, size_t size);
    // False: a page losing its last watcher is made writable at once, written or not (no page
    // rests read-only between submissions; LayerConfig::guard_rest).
    void set_resting(bool on) { resting_.store(on, std::memory_order_relaxed); }

    // Whether pages of this mapping can be guarded: protects `page`, writes it (an atomic add of
    // 0, which keeps a concurrent write of the host's) and checks the write went through once the
    // handler made the page writable again. A mapping whose write keeps faulting (a driver that
    // does not let the page become writable) gives false, not a crashed process. Once per
    // allocation, before its first watch.
    bool probe(uintptr_t page);

    // The page's bytes before its first write since it was protected; null while not written.
    const uint8_t* before_image(uintptr_t page) const;

    struct Counts {
        uint64_t faults = 0;          // pages written while protected
        uint64_t resting_faults = 0;  // pages written while resting (after their watchers went)
        uint64_t refused = 0;         // watch() calls mprotect refused
        // What the guard's mprotect calls cost (CLASTRACE_STATS): those that made pages read-only
        // (each one interrupts every CPU running another thread of the process, to drop its TLB
        // entries) and those that made them writable again; the handler's before-image copies.
        uint64_t protect_calls = 0, protected_pages = 0, protect_ns = 0, protect_cpu_ns = 0;
        uint64_t unprotect_calls = 0, unprotected_pages = 0, unprotect_ns = 0, unprotect_cpu_ns = 0;
        uint64_t before_image_ns = 0;   // in the handler: copy and mprotect, per written page
        uint64_t resting_fault_ns = 0;  // in the handler: mprotect, per page written while resting
    };
    Counts counts() const;

    // Reinstalls the handler when another one took SIGSEGV after it (the application's, say),
    // keeping that one as the handler for faults not the guard's.
    void keep_handler_first();

    // The handler's part: true when the fault at `address` was the guard's and the faulting
    // write may be retried.
    bool take_fault(uintptr_t address);
    // The handler's part: a fault the guard could not take was the probe's own write; it jumps
    // back into probe() (and returns when the fault is someone else's).
    void end_failed_probe(uintptr_t address);

private:
    // kFree: writable, unwatched; kArmed: read-only, watched; kCapturing: the handler copies it;
    // kWritten: watched, written (writable, before-image kept); kResting: read-only, unwatched.
    enum State : uint32_t { kFree, kArmed, kCapturing, kWritten, kResting };
    struct Entry {
        std::atomic<uintptr_t> page{0};  // 0: empty
        std::atomic<uint32_t> state{kFree};
        std::atomic<uint32_t> stray_faults{0};
        std::atomic<uint32_t> hot{0};       // unwatches left that make it writable rather than rest
        std::atomic<uint32_t> hot_span{0};  // `hot` at its next write while resting (0: the first)
        uint32_t watchers = 0;              // (mutex_ held; the handler never reads it)
        bool listed = false;                // in watched_ever_ (mutex_ held)
        bool uncached = false;
    };
    PageGuard(size_t page_size, Entry* table, uint8_t* slots);
    Entry* find(uintptr_t page) const;
    Entry* find_or_add(uintptr_t page);
    uint8_t* slot_of(const Entry* e) const;
    // mprotect over the runs of consecutive pages in `pages` (sorted); false at the first refusal.
    // Counted and timed in the protecting or unprotecting totals, by `protection`.
    bool protect_runs(const uintptr_t* pages, size_t count, int protection);
    // Makes `pages` (sorted) writable and unprotected (mutex_ held).
    void release(const std::vector<uintptr_t>& pages);
    // `page` lost its last watcher: resting if unwritten and not hot, free if written (mutex_
    // held). A hot unwritten page goes to `to_release` instead, for release().
    void rest(Entry* e, uintptr_t page, std::vector<uintptr_t>* to_release);
    // The handler's part for a resting page: writable again, forgotten.
    bool take_resting_fault(Entry* e);
    // Waits while a fault's handler copies the page's before-image (kCapturing).
    static void wait_while_capturing(const Entry* e);

    const size_t page_size_;
    Entry* const table_;
    uint8_t* const slots_;
    std::atomic<uint64_t> faults_{0}, refused_{0}, resting_faults_{0};
    std::atomic<bool> resting_{true};
    std::atomic<uint64_t> protect_calls_{0}, protected_pages_{0}, protect_ns_{0},
        protect_cpu_ns_{0};
    std::atomic<uint64_t> unprotect_calls_{0}, unprotected_pages_{0}, unprotect_ns_{0},
        unprotect_cpu_ns_{0};
    std::atomic<uint64_t> before_image_ns_{0}, resting_fault_ns_{0};
    std::atomic<uintptr_t> probing_page_{0};  // probe(): the page, and the thread writing it
    std::atomic<long> probing_thread_{0};
    sigjmp_buf probe_return_;
    std::mutex mutex_;                  // watch/unwatch; the handler takes none
    std::set<uintptr_t> watched_ever_;  // pages watched since their memory was last forgotten
    size_t used_ = 0;                   // table entries taken
};

}  // namespace clastrace::capture
