// SPDX-License-Identifier: Apache-2.0
// The stage ahead of the replay thread (2 or more threads, runs ahead on): on a thread of its
// own it takes records from the reader (decompression's hand-off, the FlatBuffers verifier, delta
// decoding, the reader's caches), copies each into blocks of its own, and asks the reader for
// the contents of every snapshot a record names (read_contents: the chunk decompressed again, the
// key checked), so that the replay thread receives records ready to plan and replay, and plans
// runs ahead and lays snapshots in from those answers without asking the reader (docs/replay.md
// "Threads", issue 23). Records come out in stream order, as the reader hands them out.
#pragma once

#include "cluster_speculation.h"

#include <clastrace/traces/trace_reader.h>

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <exception>
#include <memory>
#include <mutex>
#include <thread>
#include <type_traits>
#include <utility>
#include <vector>

namespace clastrace::replay::detail {

// What the stage's thread allocated and the replay thread let go: handed back so that the stage's
// thread reuses or frees it. glibc's heap arenas are per thread, and memory one thread allocates
// and another frees piles up in the first one's arena (issue 23, session 12); once the stage is
// gone (the replay's end), it is freed where it is let go.
class StageReturns {
public:
    static constexpr size_t kBlockBytes = 256u << 10;
    using Free = void (*)(void*);
    void give_block(uint8_t* block);  // kBlockBytes
    void give(void* memory, Free free);
    // On the stage's thread: a block handed back, or nullptr; frees the rest handed back.
    uint8_t* reuse_block();
    // At the stage's end: frees all it holds, and from now on what is handed back at once.
    void stage_ended();
    ~StageReturns();

    // Allocates as std::allocator does, and hands back (shared_ptr control blocks, lists).
    template <class T>
    struct Allocator {
        using value_type = T;
        // A list moved to the replay thread takes its allocator along: it is freed through it.
        using propagate_on_container_move_assignment = std::true_type;
        using propagate_on_container_swap = std::true_type;
        std::shared_ptr<StageReturns> returns;
        explicit Allocator(std::shared_ptr<StageReturns> r) : returns(std::move(r)) {}
        template <class U>
        Allocator(const Allocator<U>& other) : returns(other.returns) {}
        T* allocate(size_t n) { return static_cast<T*>(::operator new(n * sizeof(T))); }
        void deallocate(T* p, size_t) {
            returns->give(p, [](void* q) { ::operator delete(q); });
        }
        template <class U>
        bool operator==(const Allocator<U>& other) const {
            return returns == other.returns;
        }
    };

private:
    std::mutex mutex_;
    std::vector<uint8_t*> blocks_;
    std::vector<std::pair<void*, Free>> given_, freeing_;
    bool ended_ = false;
};

// Copies of records, laid one after the other in blocks shared by the copies in them: one
// allocation per block instead of one per record (session 13); a block goes back to `returns`
// when the last copy in it goes.
class RecordBlocks {
public:
    using Block = std::shared_ptr<uint8_t[]>;
    explicit RecordBlocks(std::shared_ptr<StageReturns> returns) : returns_(std::move(returns)) {}
    // A copy of `size` bytes at a 16-byte aligned place (FlatBuffers align up to 8), in *block.
    const uint8_t* copy(const uint8_t* bytes, size_t size, Block* block);

private:
    std::shared_ptr<StageReturns> returns_;
    Block block_;
    size_t capacity_ = 0, used_ = 0;
};

// The reader's answers for the contents of a record's snapshots (find_answer).
using SnapshotAnswers = std::vector<SnapshotAnswer, StageReturns::Allocator<SnapshotAnswer>>;

// One record as the stage hands it over: its copy and its snapshots' answers (one with too many
// bytes to keep is left out too: the replay thread asks the reader itself).
struct StagedRecord {
    RecordBlocks::Block block;  // holds the copy `view` points into
    traces::RecordView view;
    SnapshotAnswers resolved{SnapshotAnswers::allocator_type(nullptr)};
    uint64_t resolved_bytes = 0;  // their sizes' sum
};

class RecordStage {
public:
    // Reads `reader` on a thread of its own from now on. Every other call into the reader while
    // the stage lives takes `reader_mutex` (the reader serves one caller at a time).
    RecordStage(traces::TraceReader& reader, std::mutex& reader_mutex);
    ~RecordStage();  // stops the thread and waits for it
    RecordStage(const RecordStage&) = delete;
    RecordStage& operator=(const RecordStage&) = delete;

    // The next record in stream order, waiting for the stage when none is ready; false at the
    // end of the records. Rethrows what the stage's thread threw.
    bool next(StagedRecord* out);

private:
    // Enough to keep the replay thread fed through a chunk's decompression without holding more
    // than a few MiB of copies beyond the replay's own read-ahead window.
    static constexpr size_t kMaxReadyRecords = 1024;
    static constexpr uint64_t kMaxReadyBytes = 4ull << 20;
    // Records handed over in batches: one lock and at most one wake-up per batch, unless the
    // replay thread waits.
    static constexpr size_t kBatchRecords = 32;

    void loop();
    // Reads one record into *out under the reader's lock; false at the end.
    bool read(StagedRecord* out);
    // Its snapshots' contents, from resolved_ or the reader.
    void resolve_snapshots(StagedRecord* out);
    // Hands `batch` over (emptied); waits while the ready queue is full. False once stopping.
    bool publish(std::vector<StagedRecord>* batch, uint64_t bytes);

    traces::TraceReader& reader_;
    std::mutex& reader_mutex_;
    std::shared_ptr<StageReturns> returns_ = std::make_shared<StageReturns>();
    RecordBlocks blocks_{returns_};  // the stage thread's only
    // Bytes made on the stage's thread, handed back there when the last holder lets them go.
    RecentContents::Bytes stage_bytes(const uint8_t* data, size_t size);
    // The reader's recent answers: frames name the same contents again and again.
    static constexpr uint64_t kResolvedBytes = 8ull << 20;
    RecentContents resolved_{kResolvedBytes};  // the stage thread's only

    std::mutex mutex_;
    std::condition_variable ready_changed_;  // records published, taken, the end or stop
    // Two lists that change hands (swapped), so that only the stage's thread grows them.
    std::vector<StagedRecord> ready_;
    uint64_t ready_bytes_ = 0;
    bool ended_ = false;                         // the stage read its last record (or threw)
    bool stopping_ = false;                      // the replay no longer takes records
    bool stage_waiting_ = false;                 // for room in ready_
    std::atomic<bool> consumer_waiting_{false};  // read by the stage without the lock
    std::exception_ptr failure_;
    // The replay thread's own: records it took in one go, handed out one by one.
    std::vector<StagedRecord> taken_;
    size_t next_taken_ = 0;
    std::thread thread_;  // last: started once the members above exist
};

}  // namespace clastrace::replay::detail
