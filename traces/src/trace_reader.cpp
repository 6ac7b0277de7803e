// SPDX-License-Identifier: Apache-2.0
#include <clastrace/traces/trace_reader.h>

#include <clastrace/common/debug_assert.h>
#include <clastrace/common/hex.h>

#include <clastrace/traces/records.h>

#include "byte_planes.h"
#include "chunk_streams.h"
#include "byte_source.h"
#include "file_format.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <cinttypes>
#include <cstdio>
#include <cstring>
#include <deque>
#include <condition_variable>
#include <exception>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <system_error>
#include <thread>
#include <type_traits>
#include <unordered_map>
#include <utility>

#include <zstd.h>

namespace clastrace::traces {

namespace {

constexpr size_t kMaxDamageKept = 1000;
constexpr uint32_t kReadAheadMinRawBytes = 256u << 10;
// Reading ahead a bigger chunk would hold two of them at once; the writer's chunks are 4 MiB.
constexpr uint32_t kReadAheadMaxRawBytes = 16u << 20;
// The reader holds at most one buffer above this (the chunk being read or the one
// read_contents needs), so its memory stays near one chunk of kMaxChunkRawBytes.
constexpr uint32_t kBigBufferBytes = 32u << 20;
// The writer never frames a record the verifier rejects, so a chunk whose frames break
// this often holds no records: one more message per frame would only cost time.
constexpr uint32_t kMaxBrokenFramesPerChunk = 4;
// ChunkLocation and ContentLocation sizes in the index, and the fixed part around them.
constexpr uint64_t kIndexBytesPerChunk = 32;
constexpr uint64_t kIndexBytesPerContent = 24;
constexpr uint64_t kIndexFixedBytes = 64u << 10;

// Checksums, magics and hashes read best at their full width.
std::string hex(uint64_t v) { return common::hex(v, 16); }

// Where the bytes of one content live: which chunk, and where its frame starts in it.
struct ContentPlace {
    uint64_t size;
    uint64_t chunk_offset;
    uint32_t raw_offset;
    bool seen_in_scan;  // defined by a record the scan already passed
};

enum class ChunkStatus {
    kOk,
    kBadHeader,   // header unusable: look for the next chunk header byte by byte
    kBadPayload,  // header fine, payload not: skip exactly this chunk
    kTruncated,   // the file ends inside this chunk
    kOverBudget,  // decompressing it would pass TraceReaderOptions::max_raw_bytes: stop reading
};

enum class RecordStatus {
    kOk,
    kSkip,    // the record breaks a rule; the frames around it are fine
    kBroken,  // the frame itself is not a record (verifier, kind, body)
    kStopChunk,
};

// Bytes that are written before they are read (decompressed chunks, compressed payloads):
// growing them leaves the new bytes undefined instead of zeroing them, a pass over every
// chunk's bytes that decompression then overwrites.
template <class T>
struct UninitializedAllocator : std::allocator<T> {
    template <class U>
    struct rebind {
        using other = UninitializedAllocator<U>;
    };
    UninitializedAllocator() = default;
    template <class U>
    UninitializedAllocator(const UninitializedAllocator<U>&) noexcept {}
    template <class U>
    void construct(U* p) noexcept(std::is_nothrow_default_constructible_v<U>) {
        ::new (static_cast<void*>(p)) U;
    }
    template <class U, class... Args>
    void construct(U* p, Args&&... args) {
        ::new (static_cast<void*>(p)) U(std::forward<Args>(args)...);
    }
};
using ChunkBytes = std::vector<uint8_t, UninitializedAllocator<uint8_t>>;

// Frees a buffer whose capacity a big chunk left behind, so it does not linger.
void release_if_big(ChunkBytes& buffer, size_t needed = 0) {
    if (buffer.capacity() > kBigBufferBytes && buffer.capacity() > 2 * needed)
        ChunkBytes().swap(buffer);
}

// Sizes a buffer to n bytes, grown to exactly n: vector::resize grows to twice the old size, so
// a chunk of 3.1 MB after one of 3 MB held 6 MB (replay's peak memory was four such buffers).
void resize_exact(ChunkBytes& buffer, size_t n) {
    if (n > buffer.capacity()) {
        buffer.clear();  // nothing to move to the new buffer
        buffer.reserve(n);
    }
    buffer.resize(n);
}

// The contents record in the frame at raw offset `at` of `raw`, verified; nullopt when the frame
// overruns the bytes or holds anything else.
std::optional<ContentsRecord> contents_in_frame(const ChunkBytes& raw, uint32_t at) {
    if (at > raw.size() || raw.size() - at < format::kRecordFrameSize) return std::nullopt;
    const uint32_t rsize = format::load<uint32_t>(raw.data() + at);
    if (rsize > raw.size() - at - format::kRecordFrameSize) return std::nullopt;
    const uint8_t* bytes = raw.data() + at + format::kRecordFrameSize;
    flatbuffers::Verifier verifier(bytes, rsize, 64, 10'000'000);
    if (!fbs::VerifyRecordBuffer(verifier)) return std::nullopt;
    return contents_record(*fbs::GetRecord(bytes));
}

// What one thread needs to read a chunk: the reader uses one set on its own thread
// and one on the read-ahead task, so decompressing chunk n+1 overlaps the checks of chunk n.
struct ChunkDecoder {
    ChunkBytes compressed;
    ZSTD_DCtx* dctx = ZSTD_createDCtx();
    ChunkDecoder() = default;
    ChunkDecoder(const ChunkDecoder&) = delete;
    ChunkDecoder& operator=(const ChunkDecoder&) = delete;
    ~ChunkDecoder() { ZSTD_freeDCtx(dctx); }
};


// The real bytes of one content. Filled once, then only read: the reader's base cache, the
// read-ahead task's and the chunk the task decoded share them across the two threads.
struct RealBytes {
    std::unique_ptr<uint8_t[]> data;
    size_t size = 0;
    size_t capacity = 0;
};
using SharedBytes = std::shared_ptr<const RealBytes>;

// Buffers of RealBytes that no cache holds any more, handed out again: a content of a frame
// loop costs no fresh pages (first touches of new pages cost about as much as a copy).
class BytesPool : public std::enable_shared_from_this<BytesPool> {
public:
    // A buffer of n bytes whose contents are undefined; it comes back here once dropped.
    std::shared_ptr<RealBytes> take(size_t n) {
        std::unique_ptr<RealBytes> b;
        {
            std::lock_guard lock(mutex_);
            auto best = free_.end();  // the smallest that fits
            for (auto it = free_.begin(); it != free_.end(); ++it)
                if ((*it)->capacity >= n &&
                    (best == free_.end() || (*it)->capacity < (*best)->capacity))
                    best = it;
            if (best != free_.end()) {
                b = std::move(*best);
                free_.erase(best);
                free_bytes_ -= b->capacity;
            }
        }
        if (!b) {
            b = std::make_unique<RealBytes>();
            b->data.reset(new uint8_t[std::max<size_t>(n, 1)]);
            b->capacity = n;
            allocated_bytes_ += n;
        }
        b->size = n;
        return std::shared_ptr<RealBytes>(b.release(), [pool = shared_from_this()](RealBytes* r) {
            pool->give(r);
        });
    }

    // TraceReadStats::real_bytes_allocated.
    uint64_t allocated_bytes() const { return allocated_bytes_.load(); }

private:
    static constexpr size_t kMaxFree = 8;
    static constexpr size_t kMaxFreeBytes = size_t{32} << 20;
    void give(RealBytes* r) {
        std::unique_ptr<RealBytes> b(r);
        std::lock_guard lock(mutex_);
        if (free_.size() < kMaxFree && free_bytes_ + b->capacity <= kMaxFreeBytes) {
            free_bytes_ += b->capacity;
            free_.push_back(std::move(b));
        }
    }
    std::mutex mutex_;
    std::vector<std::unique_ptr<RealBytes>> free_;
    size_t free_bytes_ = 0;
    std::atomic<uint64_t> allocated_bytes_{0};
};

// The real bytes of the contents a scan passed last, up to a byte budget (the oldest go
// first), so that a delta's base costs a lookup rather than a walk back through its chain.
// A hash keeps the bytes it was first given: the reader compares them by identity with those
// the read-ahead task decoded against.
//
// A base that a delta has used is usually done with: the writer's next delta of that range
// names the new contents. Such bases move to a small second budget and go first, so that their
// buffers come back to the pool within a few frames instead of after 64 MiB of fresh pages
// (a page's first touch costs about what a copy of it does). A base used twice (two ranges
// that held the same bytes) is still found while it is among the used ones kept, and else
// read again through its chain.
struct RealBytesCache {
    static constexpr uint64_t kBudgetBytes = uint64_t{64} << 20;
    static constexpr uint64_t kUsedBudgetBytes = uint64_t{4} << 20;
    struct Entry {
        SharedBytes bytes;
        uint64_t sequence;  // when it was kept or last moved, to tell stale queue places
        bool used;
    };
    struct Place {
        uint64_t hash, sequence;
    };
    std::unordered_map<uint64_t, Entry> by_hash;
    std::deque<Place> oldest_first, oldest_used_first;  // places of entries gone are skipped
    uint64_t bytes_held = 0, used_bytes_held = 0;
    uint64_t next_sequence = 0;

    SharedBytes find(uint64_t hash) const {
        auto it = by_hash.find(hash);
        return it == by_hash.end() ? nullptr : it->second.bytes;
    }
    void keep(uint64_t hash, SharedBytes bytes) {
        const size_t n = bytes->size;
        if (n > kBudgetBytes / 4 || by_hash.count(hash)) return;
        while (bytes_held + n > kBudgetBytes && evict_oldest()) {}
        by_hash.emplace(hash, Entry{std::move(bytes), next_sequence, false});
        oldest_first.push_back({hash, next_sequence++});
        bytes_held += n;
    }
    // A delta was decoded against `hash`: it goes among the used bases.
    void note_used(uint64_t hash) {
        auto it = by_hash.find(hash);
        if (it == by_hash.end() || it->second.used) return;
        it->second.used = true;
        it->second.sequence = next_sequence;
        oldest_used_first.push_back({hash, next_sequence++});
        used_bytes_held += it->second.bytes->size;
        while (used_bytes_held > kUsedBudgetBytes && evict_from(oldest_used_first, true)) {}
        if (oldest_first.size() > 2 * by_hash.size() + 64) drop_stale(oldest_first, false);
    }

private:
    bool live(const Place& p, bool used) const {
        auto it = by_hash.find(p.hash);
        return it != by_hash.end() && it->second.sequence == p.sequence && it->second.used == used;
    }
    // Places of entries that moved or went, dropped at once so the queue stays near the map's size.
    void drop_stale(std::deque<Place>& queue, bool used) {
        std::erase_if(queue, [&](const Place& p) { return !live(p, used); });
    }
    bool evict_oldest() {
        return evict_from(oldest_used_first, true) || evict_from(oldest_first, false);
    }
    // Drops the oldest live entry of `queue` (true), or finds none (false).
    bool evict_from(std::deque<Place>& queue, bool used) {
        while (!queue.empty()) {
            const Place p = queue.front();
            queue.pop_front();
            if (!live(p, used)) continue;
            auto it = by_hash.find(p.hash);
            const size_t n = it->second.bytes->size;
            bytes_held -= n;
            if (used) used_bytes_held -= n;
            by_hash.erase(it);
            return true;
        }
        return false;
    }
};

// A content of the chunk read ahead that the task turned into its real bytes: a delta XORed
// with its base, or (once the trace has shown deltas) contents stored whole, copied.
struct AheadContents {
    uint32_t raw_offset = 0;
    uint64_t hash = 0;
    SharedBytes bytes;
    SharedBytes base;  // the bytes a delta was XORed with; null for contents stored whole
    // A base the task read whole from its own record (its key checked), at this place.
    bool base_read_whole = false;
    uint64_t base_chunk_offset = 0;
    uint32_t base_raw_offset = 0;
};

// Where the task saw contents stored whole before the trace's first delta (it keeps no bytes
// until then): the base of a range's first delta is read from there.
struct WholePlace {
    uint64_t chunk_offset;
    uint32_t raw_offset;
};

// A decompressed chunk the task may read besides its own, where a range's first base usually
// lies: the chunk the reader's thread holds while the task reads the next one, or one of the two
// loaded before it. Read-only on the task; the reader's thread changes only the delta records of
// the first (other frames than the whole contents the task reads) until it has waited for the
// task.
struct HeldChunk {
    uint64_t offset = UINT64_MAX;
    const ChunkBytes* bytes = nullptr;
};
constexpr size_t kOlderChunks = 2;
struct HeldChunks {
    HeldChunk loaded;
    std::array<HeldChunk, kOlderChunks> older;
};
// Delta contents came with format 1.7: before it no chunk is kept for their first bases.
constexpr uint16_t kFirstDeltaMinor = 7;
// Loads after the last chunk holding whole places that it is kept for: a range's first delta
// comes a frame after its base, which frames bigger than a chunk put two chunks later.
constexpr uint32_t kLoadsOlderKept = 2;
// A trace whose first chunks show no delta likely has none (its writer stored every content
// whole): from then on no chunk is kept for first bases until the task sees a delta.
constexpr uint32_t kLoadsBeforeFirstDelta = 4;

// The read-ahead task's own state, touched by one task at a time, and by the reader's thread
// only while no task runs.
struct AheadDecoding {
    // Places of whole contents seen before the first delta, the newest 4096 to 8192 (two
    // generations): a trace without deltas costs at most this much. A range whose first base is
    // older has its chain decoded on the reader's thread.
    static constexpr size_t kWholePlacesPerGeneration = 4096;
    RealBytesCache known;  // the real bytes of the contents the task passed last
    std::unordered_map<uint64_t, WholePlace> whole_places, older_whole_places;
    bool seen_delta = false;
    uint64_t last_place_chunk = UINT64_MAX;  // the chunk of the newest place noted

    void note_whole(uint64_t hash, WholePlace place) {
        last_place_chunk = place.chunk_offset;
        if (whole_places.size() >= kWholePlacesPerGeneration) {
            older_whole_places = std::move(whole_places);
            whole_places.clear();
        }
        whole_places.insert_or_assign(hash, place);
    }
    const WholePlace* whole_place(uint64_t hash) const {
        if (auto it = whole_places.find(hash); it != whole_places.end()) return &it->second;
        auto it = older_whole_places.find(hash);
        return it == older_whole_places.end() ? nullptr : &it->second;
    }
    ChunkBytes side_raw;  // the chunk a first delta's base was read from
    uint64_t side_offset = UINT64_MAX;
};

// A chunk read ahead of need, at the offset the reader will ask for next.
struct ReadAhead {
    uint64_t offset = 0;
    format::ChunkHeader header{};
    ChunkStatus status = ChunkStatus::kOk;
    TraceError error;
    bool decompressed = false;  // false for chunks left to the reader's thread (big or not records)
    std::vector<AheadContents> contents;  // by raw offset: what the task decoded of the chunk
};

// One job at a time on a thread kept for the reader's life. A thread per chunk read ahead
// (std::async) paid its start, its end and the release of its stack's pages every 4 MiB.
template <class Result>
class ReadAheadThread {
public:
    ReadAheadThread() = default;
    ReadAheadThread(const ReadAheadThread&) = delete;
    ReadAheadThread& operator=(const ReadAheadThread&) = delete;
    ~ReadAheadThread() {
        {
            std::lock_guard lock(mutex_);
            stop_ = true;
        }
        changed_.notify_all();
        if (thread_.joinable()) thread_.join();
    }

    // Runs `job` on the thread; false when no thread can be started (a process at its thread
    // limit), and the reader's thread then does the work itself. The job given before must have
    // been taken or dropped.
    bool run(std::function<Result()> job) {
        CLASTRACE_DEBUG_ASSERT(!given_);
        if (!thread_.joinable()) {
            try {
                thread_ = std::thread([this] { serve(); });
            } catch (const std::system_error&) {
                return false;
            }
        }
        {
            std::lock_guard lock(mutex_);
            job_ = std::move(job);
        }
        given_ = true;
        changed_.notify_all();
        return true;
    }
    // True from run() until get() or drop() (only the reader's thread calls these).
    bool valid() const { return given_; }
    void wait() {
        std::unique_lock lock(mutex_);
        changed_.wait(lock, [&] { return done_; });
    }
    Result get() {
        wait();
        given_ = false;
        std::lock_guard lock(mutex_);
        done_ = false;
        if (failure_) std::rethrow_exception(std::exchange(failure_, nullptr));
        Result r = std::move(*result_);
        result_.reset();
        return r;
    }
    void drop() {
        if (!given_) return;
        wait();
        given_ = false;
        std::lock_guard lock(mutex_);
        done_ = false;
        result_.reset();
        failure_ = nullptr;
    }

private:
    void serve() {
        std::unique_lock lock(mutex_);
        for (;;) {
            changed_.wait(lock, [&] { return stop_ || job_ != nullptr; });
            if (stop_) return;
            std::function<Result()> job = std::exchange(job_, nullptr);
            lock.unlock();
            std::optional<Result> r;
            std::exception_ptr failure;
            try {
                r.emplace(job());
            } catch (...) {
                failure = std::current_exception();
            }
            lock.lock();
            result_ = std::move(r);
            failure_ = failure;
            done_ = true;
            changed_.notify_all();
        }
    }
    std::mutex mutex_;
    std::condition_variable changed_;
    std::function<Result()> job_;  // under mutex_, like the four below
    std::optional<Result> result_;
    std::exception_ptr failure_;
    bool done_ = false;
    bool stop_ = false;
    bool given_ = false;  // the reader's thread's own
    std::thread thread_;
};

bool known_byte_planes(uint8_t planes) { return planes <= 1 || planes == 4; }

std::string unknown_planes(uint8_t planes) {
    return "lay their XOR out in " + std::to_string(planes) +
           " byte planes, which this reader does not know (0, 1 or 4)";
}

// out = `base` (the base's real bytes) XOR the delta `delta` laid out as `byte_planes` says.
// `out` may be `base`; it is `delta` only without planes.
void apply_delta(const uint8_t* delta, uint8_t byte_planes, const uint8_t* base, size_t n,
                 uint8_t* out) {
    if (byte_planes == 4) return format::xor_from_byte_planes(delta, base, n, out);
    for (size_t i = 0; i < n; ++i) out[i] = base[i] ^ delta[i];
}

// Where a record lies in file order: a delta's base must lie before it.
bool precedes(uint64_t chunk_a, uint32_t raw_a, uint64_t chunk_b, uint32_t raw_b) {
    return chunk_a < chunk_b || (chunk_a == chunk_b && raw_a < raw_b);
}

}  // namespace

struct TraceReader::Impl {
    std::string name;
    TraceReaderOptions options;
    std::unique_ptr<ByteSource> src;
    uint64_t size = 0;
    uint16_t version_major = 0;
    uint16_t version_minor = 0;
    std::vector<uint8_t> header_bytes;
    const fbs::TraceHeader* header = nullptr;
    unsigned hash_bits = 64;
    uint64_t data_start = format::kFileHeaderSize;

    // Index (when the file was finished).
    ChunkBytes index_raw;
    const fbs::TraceIndex* index = nullptr;
    uint64_t index_offset = 0;
    std::unordered_map<uint64_t, uint32_t>
        index_position;                  // chunk file offset -> place in index->chunks()
    std::vector<bool> index_chunk_read;  // by place: the scan read that records chunk

    // Decompression budget, shared with the read-ahead task.
    uint64_t raw_budget = 0;
    mutable std::atomic<uint64_t> raw_spent{0};
    bool budget_reported = false;
    bool budget_exhausted = false;

    // Streaming state.
    uint64_t pos = 0;
    bool ended = false;
    bool skipped_since_chunk = true;  // damage/seek since the last chunk: numbering may jump
    uint32_t expected_chunk_number = 0;
    ChunkDecoder decoder;
    ChunkBytes raw;
    // Read-ahead: a task decompressing the next chunk into ahead_raw with its own decoder.
    ChunkDecoder ahead_decoder;
    ChunkBytes ahead_raw;
    // The last two chunks loaded before `raw` where the task noted whole places (at
    // older_offset), kept for the task for kLoadsOlderKept loads after them (keep_loaded_as_older).
    std::array<ChunkBytes, kOlderChunks> older_raw;
    std::array<uint64_t, kOlderChunks> older_offset{UINT64_MAX, UINT64_MAX};
    uint32_t loads_past_older = 0;
    uint32_t loads_without_delta = 0;  // chunks loaded before the task saw a delta
    ReadAheadThread<ReadAhead> ahead;
    bool chunk_loaded = false;
    format::ChunkHeader chunk{};
    uint64_t chunk_offset = 0;
    size_t cursor = 0;
    uint32_t chunk_records_seen = 0;
    uint32_t chunk_submissions = 0;
    uint32_t chunk_broken_frames = 0;
    bool chunk_cut_short = false;
    bool raw_evicted =
        false;  // the loaded chunk's bytes were freed for read_contents: decompress again
    uint64_t next_submission = 0;
    // The last records chunk handed out since the scan (re)started: a chunk numbered at or
    // below it, or starting before the submissions read, repeats records already handed out.
    bool have_last_chunk = false;
    uint32_t last_chunk_number = 0;
    // A scan from the first chunk, never repositioned: only it can tell which chunks the index lists in vain.
    bool full_scan = false;
    uint64_t scan_records_claimed = 0;
    bool seeked = false;
    bool has_pending = false;
    RecordView pending;

    std::unordered_map<uint64_t, ContentPlace> contents;
    ChunkBytes side_raw;
    uint64_t side_offset = UINT64_MAX;
    // Delta contents (MemoryContentsDelta, format 1.7): the raw offsets of the loaded chunk's
    // records decoded in place (rising: the scan decodes in order), and the real bytes of recent
    // contents, the bases of deltas to come, kept once the trace has shown one delta.
    std::vector<uint32_t> decoded_in_raw;
    std::shared_ptr<BytesPool> pool = std::make_shared<BytesPool>();
    RealBytesCache resolved;
    ChunkBytes delta_copy;  // a delta's planes while it is decoded in place
    bool trace_has_deltas = false;
    // The read-ahead task decodes the deltas of the chunk it reads; the loaded chunk's results,
    // by raw offset, wait here for the checks of their records (decode_delta).
    AheadDecoding ahead_decoding;
    std::vector<AheadContents> chunk_ahead;

    std::vector<TraceError> damage;
    uint64_t damage_total = 0;
    TraceReadStats stats;

    ~Impl() { drop_read_ahead(); }

    // TraceReadStats::chunk_buffer_bytes; waits for the read-ahead task, whose buffers it counts.
    uint64_t chunk_buffer_bytes() {
        if (ahead.valid()) ahead.wait();
        return raw.capacity() + ahead_raw.capacity() + older_raw[0].capacity() +
               older_raw[1].capacity() + side_raw.capacity() + ahead_decoding.side_raw.capacity() +
               decoder.compressed.capacity() + ahead_decoder.compressed.capacity();
    }

    TraceError error(TraceErrorCode code, uint64_t offset, const std::string& problem) const {
        return make_trace_error(code, name, offset, problem);
    }
    void report(TraceErrorCode code, uint64_t offset, const std::string& problem) {
        ++damage_total;
        if (damage.size() < kMaxDamageKept) damage.push_back(error(code, offset, problem));
    }
    void report(TraceError e) {
        ++damage_total;
        if (damage.size() < kMaxDamageKept) damage.push_back(std::move(e));
    }
    // For problems that can repeat per record: past the kept ones, counting costs no message.
    template <class MakeProblem>
    void report_with(TraceErrorCode code, uint64_t offset, MakeProblem&& problem) {
        ++damage_total;
        if (damage.size() < kMaxDamageKept) damage.push_back(error(code, offset, problem()));
    }

    // Takes n bytes from the decompression budget; false (nothing taken) when they do not fit.
    bool take_from_budget(uint64_t n) const {
        uint64_t spent = raw_spent.load();
        do {
            if (spent > raw_budget || n > raw_budget - spent) return false;
        } while (!raw_spent.compare_exchange_weak(spent, spent + n));
        return true;
    }

    // Reads, checks and decompresses the chunk whose header is at `offset`.
    ChunkStatus read_chunk(uint64_t offset, format::ChunkHeader* h, ChunkBytes* out,
                           TraceError* err) {
        ChunkStatus status = read_checked_payload(decoder, offset, h, err);
        return status == ChunkStatus::kOk ? decompress(offset, *h, out, err) : status;
    }

    // decompress_payload on the reader's own thread and decoder, noting a spent budget.
    ChunkStatus decompress(uint64_t offset, const format::ChunkHeader& h, ChunkBytes* out,
                           TraceError* err) {
        ChunkStatus status = decompress_payload(decoder, offset, h, out, err);
        if (status == ChunkStatus::kOverBudget) budget_exhausted = true;
        return status;
    }

    // Frees the bytes read_contents keeps of another chunk when they are big (one big buffer
    // at a time); the chunk is read again when asked for.
    void release_side_chunk_if_big() {
        release_if_big(side_raw);
        if (side_raw.capacity() == 0) side_offset = UINT64_MAX;
    }

    // Header and compressed payload of the chunk at `offset` into d.compressed, checksums
    // checked, nothing decompressed. This and decompress_payload are safe on the read-ahead
    // task: they touch only `d`, their outputs, the budget and the (thread-safe) source.
    ChunkStatus read_checked_payload(ChunkDecoder& d, uint64_t offset, format::ChunkHeader* h,
                                     TraceError* err) const {
        ChunkBytes& compressed = d.compressed;
        if (offset > size || size - offset < format::kChunkHeaderSize) {
            *err = error(TraceErrorCode::kTruncated, offset,
                         "file ends inside a chunk header (" +
                             std::to_string(size - std::min(size, offset)) + " of " +
                             std::to_string(format::kChunkHeaderSize) + " bytes present)");
            return ChunkStatus::kTruncated;
        }
        uint8_t bytes[format::kChunkHeaderSize];
        if (!src->read_at(offset, sizeof bytes, bytes)) {
            *err = error(TraceErrorCode::kIoError, offset, "read failed: " + src->last_error());
            return ChunkStatus::kTruncated;
        }
        std::memcpy(h, bytes, sizeof *h);
        if (h->magic != format::kChunkMagic) {
            *err = error(TraceErrorCode::kBadChunk, offset,
                         "no chunk header here (magic " + hex(h->magic) + ")");
            return ChunkStatus::kBadHeader;
        }
        uint64_t computed = format::chunk_header_checksum(*h);
        if (computed != h->header_checksum) {
            *err = error(TraceErrorCode::kChecksumMismatch, offset,
                         "chunk header checksum mismatch (stored " + hex(h->header_checksum) +
                             ", computed " + hex(computed) + ")");
            return ChunkStatus::kBadHeader;
        }
        const std::string what = "chunk " + std::to_string(h->chunk_number);
        const bool is_index = h->kind == static_cast<uint16_t>(format::ChunkKind::kIndex);
        const uint64_t max_raw = is_index ? plausible_index_raw_bytes() : format::kMaxChunkRawBytes;
        if (h->raw_size > max_raw) {
            *err =
                error(TraceErrorCode::kLengthOutOfRange,
                      offset + offsetof(format::ChunkHeader, raw_size),
                      what + " claims " + std::to_string(h->raw_size) +
                          " raw bytes, over the limit of " + std::to_string(max_raw) +
                          (is_index ? " (an index of a file of " + std::to_string(size) +
                                          " bytes: one entry per chunk and per content it can hold)"
                                    : std::string()));
            return ChunkStatus::kBadHeader;
        }
        if (h->compressed_size > ZSTD_compressBound(h->raw_size)) {
            *err = error(TraceErrorCode::kLengthOutOfRange,
                         offset + offsetof(format::ChunkHeader, compressed_size),
                         what + " claims " + std::to_string(h->compressed_size) +
                             " compressed bytes, more than zstd can produce from " +
                             std::to_string(h->raw_size));
            return ChunkStatus::kBadHeader;
        }
        uint64_t payload = offset + format::kChunkHeaderSize;
        if (h->compressed_size > size - payload) {
            *err = error(TraceErrorCode::kTruncated,
                         offset + offsetof(format::ChunkHeader, compressed_size),
                         what + " claims " + std::to_string(h->compressed_size) +
                             " compressed bytes but only " + std::to_string(size - payload) +
                             " remain in the file");
            return ChunkStatus::kTruncated;
        }
        release_if_big(compressed, h->compressed_size);
        resize_exact(compressed, h->compressed_size);
        if (!src->read_at(payload, compressed.size(), compressed.data())) {
            *err = error(TraceErrorCode::kIoError, payload, "read failed: " + src->last_error());
            return ChunkStatus::kTruncated;
        }
        computed = format::checksum(compressed.data(), compressed.size());
        if (computed != h->payload_checksum) {
            *err = error(TraceErrorCode::kChecksumMismatch, payload,
                         what + " checksum mismatch (stored " + hex(h->payload_checksum) +
                             ", computed " + hex(computed) + ")");
            return ChunkStatus::kBadPayload;
        }
        return ChunkStatus::kOk;
    }

    // Decompresses d.compressed (read by read_checked_payload for header h) into `out`.
    ChunkStatus decompress_payload(ChunkDecoder& d, uint64_t offset, const format::ChunkHeader& h,
                                   ChunkBytes* out, TraceError* err) const {
        const ChunkBytes& compressed = d.compressed;
        const uint64_t payload = offset + format::kChunkHeaderSize;
        const std::string what = "chunk " + std::to_string(h.chunk_number);
        const bool streams = format::is_streams_payload(compressed.data(), compressed.size());
        if (streams && version_minor < format::kFirstStreamsMinor) {
            *err = error(TraceErrorCode::kDecompressFailed, payload,
                         what + " is a streams payload, which format 1." +
                             std::to_string(version_minor) + " (this file's) does not have: 1." +
                             std::to_string(format::kFirstStreamsMinor) + " brought them");
            return ChunkStatus::kBadPayload;
        }
        unsigned long long content =
            streams ? h.raw_size : ZSTD_getFrameContentSize(compressed.data(), compressed.size());
        if (content != h.raw_size) {
            *err = error(TraceErrorCode::kDecompressFailed, payload,
                         what + " zstd frame does not declare the chunk's " +
                             std::to_string(h.raw_size) + " raw bytes");
            return ChunkStatus::kBadPayload;
        }
        if (!take_from_budget(h.raw_size)) {
            *err = error(TraceErrorCode::kLengthOutOfRange, offset,
                         what + " would inflate " + std::to_string(compressed.size()) +
                             " bytes to " + std::to_string(h.raw_size) + ", past the budget of " +
                             std::to_string(raw_budget) + " decompressed bytes (" +
                             std::to_string(raw_spent.load()) +
                             " already spent; default 1024 x the file size, at least 1 GiB): the "
                             "rest of the file is "
                             "not read; raise the budget with --max-raw-mib "
                             "(TraceReaderOptions::max_raw_bytes)");
            return ChunkStatus::kOverBudget;
        }
        release_if_big(*out, h.raw_size);
        resize_exact(*out, h.raw_size);
        if (streams) {  // records and contents in two frames (chunk_streams.h)
            const format::StreamsProblem p =
                format::decode_streams_payload(d.dctx, compressed.data(), compressed.size(),
                                               out->data(), out->size());
            if (!p) return ChunkStatus::kOk;
            *err = error(TraceErrorCode::kDecompressFailed, payload + p.at,
                         what + " streams payload: " + p.what);
            return ChunkStatus::kBadPayload;
        }
        size_t got = ZSTD_decompressDCtx(d.dctx, out->data(), out->size(), compressed.data(),
                                         compressed.size());
        if (ZSTD_isError(got) || got != h.raw_size) {
            *err = error(TraceErrorCode::kDecompressFailed, payload,
                         what + " does not decompress: " +
                             (ZSTD_isError(got) ? ZSTD_getErrorName(got)
                                                : std::string("size differs")));
            return ChunkStatus::kBadPayload;
        }
        return ChunkStatus::kOk;
    }

    // The largest index a file of this size can need: an entry per chunk (each at least a
    // header) and per content (each costs the file at least its 8-byte key twice, in its
    // record and in the index; counted at 8 for margin), within the format's limit.
    uint64_t plausible_index_raw_bytes() const {
        uint64_t plausible = kIndexFixedBytes +
                             kIndexBytesPerChunk * (size / format::kChunkHeaderSize) +
                             kIndexBytesPerContent * (size / 8);
        return std::min<uint64_t>(plausible, format::kMaxIndexRawBytes);
    }

    // Finds the next offset >= from holding a chunk header whose checksum holds.
    uint64_t find_next_chunk(uint64_t from) {
        // Blocks grow from 4 KiB, so finding a header close by costs little even when it is
        // found again and again (a file of headers that each fail a later check).
        size_t block_size = 4096;
        constexpr size_t kMaxBlock = 1 << 20;
        std::vector<uint8_t> block;
        const uint8_t magic[4] = {'C', 'L', 'C', 'K'};
        uint64_t at = from;
        while (at + format::kChunkHeaderSize <= size) {
            const size_t step = block_size;
            block_size = std::min(kMaxBlock, block_size * 2);
            size_t n =
                static_cast<size_t>(std::min<uint64_t>(step + format::kChunkHeaderSize, size - at));
            block.resize(n);
            if (!src->read_at(at, n, block.data())) return size;
            for (size_t i = 0; i + format::kChunkHeaderSize <= n; ++i) {
                if (block[i] != magic[0] || std::memcmp(&block[i], magic, 4) != 0) continue;
                format::ChunkHeader h;
                std::memcpy(&h, &block[i], sizeof h);
                if (format::chunk_header_checksum(h) == h.header_checksum) return at + i;
            }
            if (n < step + format::kChunkHeaderSize) break;
            at += step;
        }
        return size;
    }

    void resync(uint64_t from) {
        uint64_t found = find_next_chunk(from);
        if (found > from) {
            stats.bytes_skipped += found - from;
            report(TraceErrorCode::kBadChunk, from,
                   "skipped " + std::to_string(found - from) + " bytes up to offset " +
                       std::to_string(found) +
                       (found < size ? " to reach the next intact chunk header"
                                     : " (no further chunk header found)"));
        }
        pos = found;
        skipped_since_chunk = true;
    }

    std::string record_place(uint32_t raw_offset) const {
        return "chunk " + std::to_string(chunk.chunk_number) + " record " +
               std::to_string(chunk_records_seen) + " (raw offset " + std::to_string(raw_offset) +
               ")";
    }

    // Decodes the record at `cursor` of the loaded chunk.
    RecordStatus parse_record(RecordView* out) {
        const uint32_t at = static_cast<uint32_t>(cursor);
        const size_t remaining = raw.size() - cursor;
        if (remaining < format::kRecordFrameSize) {
            report(TraceErrorCode::kInvalidRecord, chunk_offset,
                   record_place(at) + ": frame needs 8 bytes, " + std::to_string(remaining) +
                       " remain");
            return RecordStatus::kStopChunk;
        }
        uint32_t rsize = format::load<uint32_t>(raw.data() + cursor);
        uint32_t rkind = format::load<uint32_t>(raw.data() + cursor + 4);
        if (rsize > remaining - format::kRecordFrameSize) {
            report(TraceErrorCode::kLengthOutOfRange, chunk_offset,
                   record_place(at) + ": claims " + std::to_string(rsize) + " bytes, only " +
                       std::to_string(remaining - format::kRecordFrameSize) +
                       " remain in the chunk");
            return RecordStatus::kStopChunk;
        }
        const uint8_t* bytes = raw.data() + cursor + format::kRecordFrameSize;
        cursor =
            std::min<size_t>(raw.size(), cursor + format::kRecordFrameSize + format::align8(rsize));
        ++chunk_records_seen;

        flatbuffers::Verifier verifier(bytes, rsize, 64, 10'000'000);
        if (!fbs::VerifyRecordBuffer(verifier)) {
            report_with(TraceErrorCode::kInvalidRecord, chunk_offset,
                        [&] { return record_place(at) + ": fails the FlatBuffers verifier"; });
            return RecordStatus::kBroken;
        }
        const fbs::Record* record = fbs::GetRecord(bytes);
        fbs::RecordBody kind = record->body_type();
        if (static_cast<uint32_t>(kind) != rkind) {
            report_with(TraceErrorCode::kInvalidRecord, chunk_offset, [&] {
                return record_place(at) + ": frame says kind " + std::to_string(rkind) +
                       ", record holds " + std::to_string(static_cast<unsigned>(kind));
            });
            return RecordStatus::kBroken;
        }
        if (kind == fbs::RecordBody::NONE || record->body() == nullptr) {
            report_with(TraceErrorCode::kInvalidRecord, chunk_offset,
                        [&] { return record_place(at) + ": record has no body"; });
            return RecordStatus::kBroken;
        }
        if (!check_record(*record, at)) return RecordStatus::kSkip;

        out->record = record;
        out->kind = kind;
        out->bytes = bytes;
        out->size = rsize;
        out->chunk_offset = chunk_offset;
        out->chunk_number = chunk.chunk_number;
        out->raw_offset = at;
        return RecordStatus::kOk;
    }

    // Rules beyond the verifier: content keys, snapshot references, submission order.
    bool check_record(const fbs::Record& record, uint32_t at) {
        if (const std::optional<ContentsRecord> c = contents_record(record)) {
            SharedBytes ahead_bytes;  // the task's copy of the real bytes, when it made them
            if (c->delta && !decode_delta(*c, at, &ahead_bytes)) return false;
            if (!c->delta) ahead_bytes = ahead_whole_copy(*c, at);
            const uint8_t* data = c->data();
            size_t n = c->size();
            uint64_t key = options.verify_content_keys
                               ? format::content_key(data, n, c->seed, hash_bits)
                               : c->hash;
            if (key != c->hash) {
                report_with(TraceErrorCode::kContentMismatch, chunk_offset, [&] {
                    return record_place(at) + ": contents " + hex(c->hash) +
                           " hold bytes hashing to " + hex(key);
                });
                return false;
            }
            contents[c->hash] = ContentPlace{n, chunk_offset, at, true};
            if (trace_has_deltas) keep_real_bytes(c->hash, data, n, std::move(ahead_bytes));
            return true;
        }
        SnapshotLists lists = record_snapshots(record);
        bool ok = true;
        for (const SnapshotVector* list : {lists.inputs, lists.outputs}) {
            if (!list) continue;
            for (const fbs::MemorySnapshot* s : *list) {
                auto it = contents.find(s->hash());
                if (it == contents.end() || (!it->second.seen_in_scan && !seeked)) {
                    report_with(TraceErrorCode::kMissingContents, chunk_offset, [&] {
                        return record_place(at) + " (" + record_kind_name(record.body_type()) +
                               "): snapshot of address " + hex(s->address()) +
                               " refers to contents " + hex(s->hash()) +
                               " that no earlier record defines";
                    });
                    ok = false;
                } else if (it->second.size != s->size()) {
                    report_with(TraceErrorCode::kContentMismatch, chunk_offset, [&] {
                        return record_place(at) + " (" + record_kind_name(record.body_type()) +
                               "): snapshot of address " + hex(s->address()) + " has size " +
                               std::to_string(s->size()) + " but contents " + hex(s->hash()) +
                               " hold " + std::to_string(it->second.size) + " bytes";
                    });
                    ok = false;
                }
            }
        }
        if (!ok) return false;
        if (const auto* q = record.body_as_QueueSubmit()) {
            if (q->submission_index() != next_submission) {
                report_with(TraceErrorCode::kInvalidRecord, chunk_offset, [&] {
                    return record_place(at) + ": submission_index " +
                           std::to_string(q->submission_index()) + ", expected " +
                           std::to_string(next_submission);
                });
            }
            next_submission = q->submission_index() + 1;
            ++chunk_submissions;
        }
        return true;
    }

    // Turns the delta `c` (in the loaded chunk at raw offset `at`) into its real bytes, in
    // place, so that every consumer of the record sees them. False (reported) when its base is
    // unknown, later in the file, of another size or unreadable, or its layout is unknown.
    // When the read-ahead task decoded it against the same base bytes, its result is copied in
    // (*ahead_bytes: those bytes, to keep as a base).
    bool decode_delta(const ContentsRecord& c, uint32_t at, SharedBytes* ahead_bytes) {
        auto problem = [&](TraceErrorCode code, const std::string& why) {
            report_with(code, chunk_offset, [&] {
                return record_place(at) + ": delta contents " + hex(c.hash) + " " + why;
            });
            return false;
        };
        if (!known_byte_planes(c.byte_planes))
            return problem(TraceErrorCode::kContentMismatch, unknown_planes(c.byte_planes));
        auto base = contents.find(c.base_hash);
        if (base == contents.end() || (!base->second.seen_in_scan && !seeked) ||
            !precedes(base->second.chunk_offset, base->second.raw_offset, chunk_offset, at))
            return problem(TraceErrorCode::kMissingContents,
                           "name the base " + hex(c.base_hash) +
                               ", which no earlier record defines");
        const size_t n = c.size();
        if (base->second.size != n)
            return problem(TraceErrorCode::kContentMismatch,
                           "hold " + std::to_string(n) + " bytes but their base " +
                               hex(c.base_hash) + " holds " + std::to_string(base->second.size));
        // Decoded into the reader's own chunk bytes, so the record is handed out decoded.
        auto* data = const_cast<uint8_t*>(c.data());
        const AheadContents* ahead = ahead_contents_at(at);
        if (ahead && ahead_used_my_base(*ahead, c, base->second)) {
            if (n) std::memcpy(data, ahead->bytes->data.get(), n);
            *ahead_bytes = ahead->bytes;
            ++stats.deltas_decoded_ahead;
        } else if (TraceError e = decode_delta_here(c, data)) {
            return problem(e.code, "cannot be decoded: " + e.message);
        }
        decoded_in_raw.push_back(at);
        trace_has_deltas = true;
        resolved.note_used(c.base_hash);
        return true;
    }

    // decode_delta on this thread: the base's real bytes are those the scan kept (usually), else
    // resolved through its chain; the planes are read from a copy, as each output byte gathers
    // from all four of them.
    TraceError decode_delta_here(const ContentsRecord& c, uint8_t* data) {
        const size_t n = c.size();
        SharedBytes kept = resolved.find(c.base_hash);
        std::vector<uint8_t> resolved_base;
        if (!kept) {
            if (TraceError e = resolve_contents(c.base_hash, &resolved_base, false)) return e;
        }
        const uint8_t* base_bytes = kept ? kept->data.get() : resolved_base.data();
        const uint8_t* delta = data;
        if (c.byte_planes == 4) {
            delta_copy.assign(data, data + n);
            delta = delta_copy.data();
        }
        if (n) apply_delta(delta, c.byte_planes, base_bytes, n, data);
        return {};
    }

    // What the read-ahead task made of the record at raw offset `at` of the loaded chunk.
    const AheadContents* ahead_contents_at(uint32_t at) const {
        auto it = std::lower_bound(chunk_ahead.begin(), chunk_ahead.end(), at,
                                   [](const AheadContents& a, uint32_t offset) {
                                       return a.raw_offset < offset;
                                   });
        return it != chunk_ahead.end() && it->raw_offset == at ? &*it : nullptr;
    }

    // True when the task decoded delta `c` against the very bytes this thread would use: the
    // base bytes it keeps (the same buffer, not merely equal bytes), or, keeping none, those of
    // the whole record at the base's place (which resolve_contents would read and key-check).
    bool ahead_used_my_base(const AheadContents& a, const ContentsRecord& c,
                            const ContentPlace& base) const {
        if (!a.base || a.hash != c.hash || a.bytes->size != c.size()) return false;
        if (SharedBytes mine = resolved.find(c.base_hash)) return mine == a.base;
        return a.base_read_whole && a.base_chunk_offset == base.chunk_offset &&
               a.base_raw_offset == base.raw_offset;
    }

    // The task's copy of whole contents `c` (at raw offset `at` of the loaded chunk): the
    // same bytes, copied on the task.
    SharedBytes ahead_whole_copy(const ContentsRecord& c, uint32_t at) const {
        const AheadContents* a = ahead_contents_at(at);
        return a && !a->base && a->hash == c.hash && a->bytes->size == c.size() ? a->bytes
                                                                                : nullptr;
    }

    SharedBytes copy_of(const uint8_t* data, size_t n) {
        std::shared_ptr<RealBytes> b = pool->take(n);
        if (n) std::memcpy(b->data.get(), data, n);
        return b;
    }

    // Keeps real bytes as a base for deltas to come: the task's copy when there is one.
    void keep_real_bytes(uint64_t hash, const uint8_t* data, size_t n, SharedBytes ahead) {
        if (n > RealBytesCache::kBudgetBytes / 4 || resolved.by_hash.count(hash)) return;
        resolved.keep(hash, ahead ? std::move(ahead) : copy_of(data, n));
    }

    bool decoded_in_place(uint32_t raw_offset) const {
        return std::binary_search(decoded_in_raw.begin(), decoded_in_raw.end(), raw_offset);
    }

    void close_chunk() {
        decoded_in_raw.clear();
        if (chunk_loaded && !chunk_cut_short && chunk_records_seen != chunk.record_count) {
            report(TraceErrorCode::kInvalidRecord, chunk_offset,
                   "chunk " + std::to_string(chunk.chunk_number) + " header says " +
                       std::to_string(chunk.record_count) + " records, its payload holds " +
                       std::to_string(chunk_records_seen));
        }
        if (chunk_loaded && !chunk_cut_short && chunk_records_seen == chunk.record_count) {
            check_submissions_against_index();
        }
        chunk_loaded = false;
        raw_evicted = false;
    }

    // A chunk is cut short after its first few broken frames: the rest of a chunk that
    // breaks like that (a hostile one: 256 MiB of zeros is 2^25 broken frames) holds nothing.
    void stop_chunk_after_broken_frames() {
        report(TraceErrorCode::kInvalidRecord, chunk_offset,
               "chunk " + std::to_string(chunk.chunk_number) + ": " +
                   std::to_string(chunk_broken_frames) + " broken record frames; the remaining " +
                   std::to_string(raw.size() - cursor) + " raw bytes of the chunk are skipped");
        stats.bytes_skipped += raw.size() - cursor;
        chunk_cut_short = true;
        close_chunk();
    }

    // The chunk being read, again, after read_contents freed its bytes for another big chunk.
    bool reload_evicted_chunk() {
        release_side_chunk_if_big();
        format::ChunkHeader h{};
        TraceError err;
        if (read_chunk(chunk_offset, &h, &raw, &err) != ChunkStatus::kOk) {
            report_budget_or(std::move(err));
            chunk_cut_short = true;
            close_chunk();
            return false;
        }
        raw_evicted = false;
        decoded_in_raw.clear();  // fresh bytes: the deltas in them are encoded again
        return true;
    }

    // Budget damage is said once; other errors each time.
    void report_budget_or(TraceError err) {
        if (err.code == TraceErrorCode::kLengthOutOfRange && budget_exhausted) {
            if (budget_reported) return;
            budget_reported = true;
        }
        report(std::move(err));
    }

    uint64_t ahead_started_at = UINT64_MAX;
    uint64_t ahead_offset() const { return ahead_started_at; }

    // Reads the chunk at `offset` on the task while the reader's thread reads `held.loaded`.
    void start_read_ahead(uint64_t offset, HeldChunks held) {
        drop_read_ahead();
        if (offset >= size || size - offset < format::kChunkHeaderSize) return;
        const bool started = ahead.run([this, offset, held] {
            ReadAhead r;
            r.offset = offset;
            r.status = read_checked_payload(ahead_decoder, offset, &r.header, &r.error);
            if (r.status == ChunkStatus::kOk &&
                r.header.kind == static_cast<uint16_t>(format::ChunkKind::kRecords) &&
                r.header.raw_size <= kReadAheadMaxRawBytes) {
                r.status =
                    decompress_payload(ahead_decoder, offset, r.header, &ahead_raw, &r.error);
                r.decompressed = r.status == ChunkStatus::kOk;
                if (r.decompressed && options.decode_deltas_ahead)
                    r.contents = decode_ahead(offset, ahead_raw, held);
            }
            return r;
        });
        if (started) ahead_started_at = offset;
    }

    // Before the loaded chunk's buffer takes another chunk (no task runs): while the trace has
    // shown no delta, its bytes stay as the older chunk the task may read a range's first base
    // from (frames bigger than a chunk put it two chunks back), instead of decompressing it again.
    void keep_loaded_as_older() {
        const uint64_t last = ahead_decoding.last_place_chunk;
        const bool deltas_likely =
            ahead_decoding.seen_delta || ++loads_without_delta <= kLoadsBeforeFirstDelta;
        if (deltas_likely && version_minor >= kFirstDeltaMinor && !raw.empty() &&
            last != UINT64_MAX && chunk_offset <= last && raw.size() <= kReadAheadMaxRawBytes) {
            // The oldest buffer goes to `raw`, to be filled with the next chunk.
            std::swap(older_raw[1], older_raw[0]);
            std::swap(older_raw[0], raw);
            older_offset[1] = older_offset[0];
            older_offset[0] = chunk_offset;
            loads_past_older = 0;
        } else if (++loads_past_older > kLoadsOlderKept) {
            for (size_t i = 0; i < kOlderChunks; ++i) {
                ChunkBytes().swap(older_raw[i]);
                older_offset[i] = UINT64_MAX;
            }
        }
    }

    // The chunks the task may read besides its own (HeldChunk): `loaded` and the older ones.
    HeldChunks held_chunks(HeldChunk loaded) const {
        return {loaded,
                {HeldChunk{older_offset[0], &older_raw[0]},
                 HeldChunk{older_offset[1], &older_raw[1]}}};
    }

    // The read-ahead task's result; nullopt when the task failed (it threw: out of memory), and
    // the chunk is then read on this thread, whose errors carry the file and the offset.
    std::optional<ReadAhead> take_read_ahead() {
        ahead_started_at = UINT64_MAX;
        try {
            return ahead.get();
        } catch (const std::exception&) {
            return std::nullopt;
        }
    }

    // On the read-ahead task: the real bytes of the contents of chunk `r` (at `offset`) that it
    // can make (deltas whose base it holds, and once the trace has shown deltas, contents stored
    // whole), for the reader's thread to check and take. The records are checked again there,
    // with their damage reported; here a frame that breaks a rule is passed over. Touches only
    // ahead_decoding, ahead_decoder, the pool, the budget and the (thread-safe) source.
    std::vector<AheadContents> decode_ahead(uint64_t offset, const ChunkBytes& r,
                                            HeldChunks held = {}) {
        std::vector<AheadContents> out;
        AheadDecoding& a = ahead_decoding;
        bool read_a_base = false;
        size_t next_frame = 0;
        while (r.size() - next_frame >= format::kRecordFrameSize) {
            const auto at = static_cast<uint32_t>(next_frame);
            const uint32_t rsize = format::load<uint32_t>(r.data() + at);
            const uint32_t rkind = format::load<uint32_t>(r.data() + at + 4);
            if (rsize > r.size() - at - format::kRecordFrameSize) break;
            next_frame = std::min<size_t>(r.size(), next_frame + format::kRecordFrameSize +
                                                        format::align8(rsize));
            if (rkind != static_cast<uint32_t>(fbs::RecordBody::MemoryContents) &&
                rkind != static_cast<uint32_t>(fbs::RecordBody::MemoryContentsDelta))
                continue;
            const std::optional<ContentsRecord> c = contents_in_frame(r, at);
            if (!c) continue;
            if (!c->delta && !a.seen_delta) {
                a.note_whole(c->hash, WholePlace{offset, at});
                continue;
            }
            AheadContents made;
            made.raw_offset = at;
            made.hash = c->hash;
            if (c->delta) {
                a.seen_delta = true;
                if (!decode_delta_ahead(offset, r, held, *c, &made, &read_a_base)) continue;
            } else {
                std::shared_ptr<RealBytes> b = pool->take(c->size());
                if (c->size()) std::memcpy(b->data.get(), c->data(), c->size());
                made.bytes = std::move(b);
            }
            a.known.keep(made.hash, made.bytes);
            out.push_back(std::move(made));
        }
        // The chunk a first delta's base came from is worth keeping only while they come.
        if (!read_a_base) {
            ChunkBytes().swap(a.side_raw);
            a.side_offset = UINT64_MAX;
        }
        return out;
    }

    // On the task: delta `c` (at made->raw_offset of chunk `r`) XORed with the base the task
    // holds, or with the base's whole record read from where the task saw it.
    bool decode_delta_ahead(uint64_t offset, const ChunkBytes& r, HeldChunks held,
                            const ContentsRecord& c, AheadContents* made, bool* read_a_base) {
        if (!known_byte_planes(c.byte_planes)) return false;
        made->base = ahead_decoding.known.find(c.base_hash);
        if (!made->base) {
            const WholePlace* place = ahead_decoding.whole_place(c.base_hash);
            if (!place) return false;
            made->base = read_whole_ahead(offset, r, held, c.base_hash, *place, read_a_base);
            if (!made->base) return false;
            made->base_read_whole = true;
            made->base_chunk_offset = place->chunk_offset;
            made->base_raw_offset = place->raw_offset;
        }
        const size_t n = c.size();
        if (made->base->size != n) return false;
        std::shared_ptr<RealBytes> bytes = pool->take(n);
        if (n) apply_delta(c.data(), c.byte_planes, made->base->data.get(), n, bytes->data.get());
        made->bytes = std::move(bytes);
        ahead_decoding.known.note_used(c.base_hash);
        return true;
    }

    // On the task: whole contents `hash` at `place`, from chunk `r` (at `offset`), a chunk the
    // reader's thread holds, or else decompressed with the task's decoder (*decompressed set), its
    // key checked (as resolve_contents checks it); null when anything is off, which leaves the
    // delta to the reader's thread.
    SharedBytes read_whole_ahead(uint64_t offset, const ChunkBytes& r, HeldChunks held,
                                 uint64_t hash, WholePlace place, bool* decompressed) {
        AheadDecoding& a = ahead_decoding;
        const ChunkBytes* source = place.chunk_offset == offset ? &r : nullptr;
        for (const HeldChunk& c : {held.loaded, held.older[0], held.older[1]})
            if (!source && c.bytes && c.offset == place.chunk_offset) source = c.bytes;
        if (!source) {
            *decompressed = true;
            if (a.side_offset != place.chunk_offset) {
                a.side_offset = UINT64_MAX;
                format::ChunkHeader h{};
                TraceError err;
                if (read_checked_payload(ahead_decoder, place.chunk_offset, &h, &err) !=
                        ChunkStatus::kOk ||
                    decompress_payload(ahead_decoder, place.chunk_offset, h, &a.side_raw, &err) !=
                        ChunkStatus::kOk)
                    return nullptr;
                a.side_offset = place.chunk_offset;
            }
            source = &a.side_raw;
        }
        const std::optional<ContentsRecord> c = contents_in_frame(*source, place.raw_offset);
        if (!c || c->delta || c->hash != hash ||
            format::content_key(c->data(), c->size(), c->seed, hash_bits) != hash)
            return nullptr;
        std::shared_ptr<RealBytes> b = pool->take(c->size());
        if (c->size()) std::memcpy(b->data.get(), c->data(), c->size());
        return b;
    }

    void drop_read_ahead() {
        ahead.drop();
        ahead_started_at = UINT64_MAX;
    }

    // The chunk at `pos`: from the read-ahead when it read this offset, else read here.
    // With *have_raw false and status ok only the checked compressed payload is in `decoder`.
    ChunkStatus take_chunk(format::ChunkHeader* h, TraceError* err, bool* have_raw) {
        *have_raw = false;
        std::optional<ReadAhead> taken;
        if (ahead.valid() && ahead_offset() == pos) taken = take_read_ahead();
        if (taken) {
            ReadAhead& r = *taken;
            *h = r.header;
            *err = std::move(r.error);
            if (r.status == ChunkStatus::kOverBudget) budget_exhausted = true;
            chunk_ahead = std::move(r.contents);
            if (r.decompressed) {
                keep_loaded_as_older();
                std::swap(raw, ahead_raw);
                release_if_big(ahead_raw);
                *have_raw = true;
            } else if (r.status == ChunkStatus::kOk) {
                std::swap(decoder.compressed, ahead_decoder.compressed);
            }
            return r.status;
        }
        drop_read_ahead();
        chunk_ahead.clear();
        return read_checked_payload(decoder, pos, h, err);
    }

    // Loads the next intact record chunk; false at the end of the records.
    bool advance_chunk() {
        for (;;) {
            if (pos >= size) {
                finish_scan();
                return false;
            }
            TraceError err;
            format::ChunkHeader h{};
            bool have_raw = false;
            ChunkStatus status = take_chunk(&h, &err, &have_raw);
            const uint64_t here = pos;
            const bool is_records = h.kind == static_cast<uint16_t>(format::ChunkKind::kRecords);
            if ((status == ChunkStatus::kOk || status == ChunkStatus::kBadPayload) && is_records) {
                check_chunk_against_index(here, h);
            }
            if (status == ChunkStatus::kOk && is_records) {
                if (!in_order(here, h)) {
                    pos += format::kChunkHeaderSize + h.compressed_size;
                    continue;
                }
                if (!have_raw) {
                    if (h.raw_size > kBigBufferBytes) release_side_chunk_if_big();
                    keep_loaded_as_older();
                    status = decompress(here, h, &raw, &err);
                    // What the task does for the chunks it reads, here (no task runs now): its
                    // bases then follow every chunk of the scan.
                    if (status == ChunkStatus::kOk && options.decode_deltas_ahead)
                        chunk_ahead = decode_ahead(here, raw, held_chunks({}));
                }
            }
            // Reading ahead pays for big chunks; for small ones a task costs more than it hides.
            if (status == ChunkStatus::kOk && is_records && h.raw_size >= kReadAheadMinRawBytes) {
                start_read_ahead(pos + format::kChunkHeaderSize + h.compressed_size,
                                 held_chunks({here, &raw}));
            }
            switch (status) {
            case ChunkStatus::kOverBudget:
                report_budget_or(std::move(err));
                ++stats.chunks_damaged;
                pos = size;
                return false;
            case ChunkStatus::kTruncated:
                report(std::move(err));
                ++stats.chunks_damaged;
                pos = size;
                return false;
            case ChunkStatus::kBadHeader:
                report(std::move(err));
                resync(pos + 1);
                continue;
            case ChunkStatus::kBadPayload:
                report(std::move(err));
                ++stats.chunks_damaged;
                pos += format::kChunkHeaderSize + h.compressed_size;
                skipped_since_chunk = true;
                continue;
            case ChunkStatus::kOk: break;
            }
            pos += format::kChunkHeaderSize + h.compressed_size;
            if (h.kind == static_cast<uint16_t>(format::ChunkKind::kIndex)) {
                if (reached_index_chunk(here, pos)) {
                    finish_scan();
                    return false;
                }
                continue;
            }
            if (!is_records) {
                // Kinds added by a newer minor version are skipped; in a file this reader
                // fully knows, an unknown kind is a records chunk whose label was changed.
                if (version_minor <= format::kVersionMinor) {
                    report(TraceErrorCode::kBadChunk, here,
                           "chunk " + std::to_string(h.chunk_number) + " has kind " +
                               std::to_string(h.kind) + ", which format " +
                               std::to_string(version_major) + "." + std::to_string(version_minor) +
                               " does not define; its " + std::to_string(h.record_count) +
                               " records are skipped");
                    ++stats.chunks_damaged;
                }
                continue;
            }
            if (!skipped_since_chunk && h.chunk_number != expected_chunk_number) {
                report(TraceErrorCode::kBadChunk, here,
                       "chunk number " + std::to_string(h.chunk_number) + " where " +
                           std::to_string(expected_chunk_number) +
                           " was expected (chunks missing or reordered)");
            }
            if (!skipped_since_chunk && h.first_submission != next_submission) {
                report(TraceErrorCode::kBadChunk, here,
                       "chunk " + std::to_string(h.chunk_number) + " starts at submission " +
                           std::to_string(h.first_submission) + " but " +
                           std::to_string(next_submission) + " submissions precede it");
            }
            next_submission = h.first_submission;
            expected_chunk_number = h.chunk_number + 1;
            have_last_chunk = true;
            last_chunk_number = h.chunk_number;
            skipped_since_chunk = false;
            chunk = h;
            chunk_offset = here;
            chunk_loaded = true;
            chunk_cut_short = false;
            raw_evicted = false;
            cursor = 0;
            chunk_records_seen = 0;
            chunk_submissions = 0;
            chunk_broken_frames = 0;
            scan_records_claimed += h.record_count;
            ++stats.chunks_read;
            stats.raw_bytes += h.raw_size;
            stats.compressed_bytes += h.compressed_size;
            return true;
        }
    }

    // False for a chunk that repeats or goes back (a duplicated or reordered chunk): its
    // records would hand out submissions already handed out, so they are skipped.
    bool in_order(uint64_t at, const format::ChunkHeader& h) {
        if (!have_last_chunk ||
            (h.chunk_number > last_chunk_number && h.first_submission >= next_submission)) {
            return true;
        }
        report(TraceErrorCode::kBadChunk, at,
               "chunk " + std::to_string(h.chunk_number) + " (first submission " +
                   std::to_string(h.first_submission) + ") comes after chunk " +
                   std::to_string(last_chunk_number) + " and " + std::to_string(next_submission) +
                   " submissions: a repeated or reordered chunk; its " +
                   std::to_string(h.record_count) +
                   " records are skipped so that no record is handed out twice");
        ++stats.chunks_damaged;
        skipped_since_chunk = true;
        return false;
    }

    // A records chunk's header against the index's entry for its offset.
    void check_chunk_against_index(uint64_t at, const format::ChunkHeader& h) {
        if (!index) return;
        auto it = index_position.find(at);
        if (it == index_position.end()) {
            report(TraceErrorCode::kBadIndex, at,
                   "chunk " + std::to_string(h.chunk_number) +
                       " is a records chunk the index does not list");
            return;
        }
        CLASTRACE_DEBUG_ASSERT(it->second < index_chunk_read.size());
        const fbs::ChunkLocation* c = index->chunks()->Get(it->second);
        index_chunk_read[it->second] = true;
        std::string differs;
        auto compare = [&](const char* field, uint64_t listed, uint64_t read) {
            if (listed != read) {
                differs += std::string(differs.empty() ? "" : ", ") + field + " " +
                           std::to_string(listed) + " in the index, " + std::to_string(read) +
                           " in the chunk";
            }
        };
        compare("chunk number", it->second, h.chunk_number);
        compare("first submission", c->first_submission(), h.first_submission);
        compare("record count", c->record_count(), h.record_count);
        compare("raw size", c->raw_size(), h.raw_size);
        compare("compressed size", c->compressed_size(), h.compressed_size);
        if (!differs.empty()) {
            report(TraceErrorCode::kBadIndex, at,
                   "index entry " + std::to_string(it->second) +
                       " disagrees with the chunk there: " + differs);
        }
    }

    // QueueSubmits of a fully read chunk against its index entry.
    void check_submissions_against_index() {
        if (!index) return;
        auto it = index_position.find(chunk_offset);
        if (it == index_position.end()) return;
        uint32_t listed = index->chunks()->Get(it->second)->submission_count();
        if (listed != chunk_submissions) {
            report(TraceErrorCode::kBadIndex, chunk_offset,
                   "index entry " + std::to_string(it->second) + " says chunk " +
                       std::to_string(chunk.chunk_number) + " holds " + std::to_string(listed) +
                       " submissions, it holds " + std::to_string(chunk_submissions));
        }
    }

    // At the end of a scan from the first chunk: chunks the index lists that were not read,
    // and, when nothing else was damaged, the index's totals against what was read.
    void finish_scan() {
        if (!index || !full_scan || budget_exhausted) return;
        full_scan = false;  // once per scan
        const auto* chunks = index->chunks();
        for (uint32_t i = 0; i < chunks->size(); ++i) {
            if (index_chunk_read[i]) continue;
            report_with(TraceErrorCode::kBadIndex, chunks->Get(i)->file_offset(), [&] {
                return "index entry " + std::to_string(i) + " lists a records chunk at offset " +
                       std::to_string(chunks->Get(i)->file_offset()) +
                       " that the scan did not read as one";
            });
        }
        if (damage_total != 0) return;
        if (index->record_count() != scan_records_claimed ||
            index->submission_count() != next_submission) {
            report(TraceErrorCode::kBadIndex, index_offset,
                   "index counts " + std::to_string(index->record_count()) + " records and " +
                       std::to_string(index->submission_count()) +
                       " submissions, the chunks hold " + std::to_string(scan_records_claimed) +
                       " and " + std::to_string(next_submission));
        }
    }

    // True when this index chunk ends the records: the one the trailer points at, or,
    // without a usable trailer at the end, one followed by a trailer. Any other index
    // chunk is damage, and the chunks after it are still read.
    bool reached_index_chunk(uint64_t at, uint64_t after) {
        if (index) {
            if (at == index_offset) return true;
            report(TraceErrorCode::kBadIndex, at,
                   "index chunk here but the trailer points at offset " +
                       std::to_string(index_offset) + "; the chunks after it are still read");
            return false;
        }
        if (after == size) return true;
        if (size - after >= format::kTrailerSize) {
            format::Trailer t{};
            if (src->read_at(after, sizeof t, reinterpret_cast<uint8_t*>(&t)) &&
                std::memcmp(t.magic, format::kTrailerMagic, 8) == 0 &&
                format::trailer_checksum(t) == t.checksum) {
                if (after + format::kTrailerSize < size) {
                    report(TraceErrorCode::kTrailingBytes, after + format::kTrailerSize,
                           std::to_string(size - after - format::kTrailerSize) +
                               " bytes after the trailer");
                }
                return true;
            }
        }
        return false;
    }

    bool next(RecordView* out) {
        if (has_pending) {
            *out = pending;
            has_pending = false;
            ++stats.records;
            return true;
        }
        for (;;) {
            if (chunk_loaded && raw_evicted && !reload_evicted_chunk()) continue;
            if (chunk_loaded && cursor < raw.size()) {
                RecordStatus s = parse_record(out);
                if (s == RecordStatus::kOk) {
                    ++stats.records;
                    return true;
                }
                ++stats.records_damaged;
                if (s == RecordStatus::kBroken &&
                    ++chunk_broken_frames >= kMaxBrokenFramesPerChunk) {
                    stop_chunk_after_broken_frames();
                } else if (s == RecordStatus::kStopChunk) {
                    chunk_cut_short = true;
                    close_chunk();
                }
                continue;
            }
            if (chunk_loaded) close_chunk();
            if (ended) return false;
            if (!advance_chunk()) {
                ended = true;
                return false;
            }
        }
    }

    void restart_at(uint64_t offset) {
        drop_read_ahead();
        decoded_in_raw.clear();
        chunk_ahead.clear();
        chunk_loaded = false;
        raw_evicted = false;
        has_pending = false;
        ended = false;
        pos = offset;
        skipped_since_chunk = true;
        have_last_chunk = false;
        full_scan = false;
    }

    TraceError seek(uint64_t k) {
        seeked = true;
        if (index) {
            if (k >= index->submission_count()) {
                return error(TraceErrorCode::kInvalidArgument, 0,
                             "submission " + std::to_string(k) + " requested, the trace has " +
                                 std::to_string(index->submission_count()));
            }
            const auto* chunks = index->chunks();
            const fbs::ChunkLocation* found = nullptr;
            for (const fbs::ChunkLocation* c : *chunks) {
                if (c->submission_count() > 0 && c->first_submission() <= k &&
                    k - c->first_submission() < c->submission_count()) {
                    found = c;
                    break;
                }
            }
            if (!found || found->file_offset() < data_start || found->file_offset() >= size) {
                return error(TraceErrorCode::kBadIndex, index_offset,
                             "index lists no chunk holding submission " + std::to_string(k));
            }
            restart_at(found->file_offset());
        } else {
            restart_at(data_start);
        }
        RecordView v;
        while (next(&v)) {
            if (v.kind != fbs::RecordBody::QueueSubmit) continue;
            uint64_t at = v.record->body_as_QueueSubmit()->submission_index();
            if (at == k) {
                pending = v;
                has_pending = true;
                --stats.records;  // handed out again by next()
                return {};
            }
            if (at > k) break;
        }
        return error(TraceErrorCode::kInvalidArgument, 0,
                     "submission " + std::to_string(k) + " not found" +
                         (index ? "" : " (trace has no index)"));
    }

    // The record of contents `hash`, from the loaded chunk or the one read_contents keeps
    // (decompressed when needed), and whether it holds the real bytes (stored whole, or a delta
    // the scan decoded); valid until the next locate or chunk change. The chunk being
    // read gives a big buffer up for it only when `may_evict_raw` (not while a record of it is
    // being decoded).
    TraceError locate(uint64_t hash, bool may_evict_raw, ContentsRecord* found, ContentPlace* where,
                      bool* real) {
        auto it = contents.find(hash);
        if (it == contents.end()) {
            return error(TraceErrorCode::kMissingContents, 0,
                         "no contents with hash " + hex(hash) + " in the trace");
        }
        const ContentPlace place = it->second;
        *where = place;
        const ChunkBytes* source = nullptr;
        if (chunk_loaded && !raw_evicted && place.chunk_offset == chunk_offset) {
            source = &raw;
        } else {
            if (side_offset != place.chunk_offset) {
                format::ChunkHeader h{};
                TraceError err;
                side_offset = UINT64_MAX;
                ChunkStatus status = read_checked_payload(decoder, place.chunk_offset, &h, &err);
                if (status == ChunkStatus::kOk) {
                    // Two big buffers at once would double the reader's memory: the chunk
                    // being read gives its bytes up and is decompressed again by next().
                    if (may_evict_raw && h.raw_size > kBigBufferBytes &&
                        raw.capacity() > kBigBufferBytes && chunk_loaded) {
                        if (ahead.valid()) ahead.wait();  // it may be reading `raw` (HeldChunk)
                        ChunkBytes().swap(raw);
                        raw_evicted = true;
                        decoded_in_raw.clear();
                    }
                    status = decompress(place.chunk_offset, h, &side_raw, &err);
                }
                if (status == ChunkStatus::kOverBudget) report_budget_or(err);
                if (status != ChunkStatus::kOk) return err;
                side_offset = place.chunk_offset;
            }
            source = &side_raw;
        }
        const ChunkBytes& r = *source;
        auto bad = [&](const std::string& why) {
            return error(TraceErrorCode::kBadIndex, place.chunk_offset,
                         "contents " + hex(hash) + " not found at raw offset " +
                             std::to_string(place.raw_offset) + ": " + why);
        };
        if (place.raw_offset > r.size() || r.size() - place.raw_offset < format::kRecordFrameSize)
            return bad("outside the chunk");
        uint32_t rsize = format::load<uint32_t>(r.data() + place.raw_offset);
        if (rsize > r.size() - place.raw_offset - format::kRecordFrameSize)
            return bad("frame overruns the chunk");
        const uint8_t* bytes = r.data() + place.raw_offset + format::kRecordFrameSize;
        flatbuffers::Verifier verifier(bytes, rsize, 64, 10'000'000);
        if (!fbs::VerifyRecordBuffer(verifier)) return bad("record fails the verifier");
        const std::optional<ContentsRecord> c = contents_record(*fbs::GetRecord(bytes));
        if (!c || c->hash != hash) return bad("another record is there");
        if (c->delta && !known_byte_planes(c->byte_planes)) {
            return error(TraceErrorCode::kContentMismatch, place.chunk_offset,
                         "delta contents " + hex(hash) + " " + unknown_planes(c->byte_planes));
        }
        // The loaded chunk's deltas the scan passed hold their real bytes already.
        *real = !c->delta || (source == &raw && decoded_in_place(place.raw_offset));
        *found = *c;
        return {};
    }

    // The real bytes of contents `hash`: a delta's chain of bases is walked back to contents
    // held whole (stored whole, decoded by the scan, or kept in `resolved`), then XORed forward.
    // Each base must lie before its delta, so the walk ends, however the file was crafted.
    TraceError resolve_contents(uint64_t hash, std::vector<uint8_t>* out, bool may_evict_raw) {
        if (SharedBytes known = resolved.find(hash)) {
            out->assign(known->data.get(), known->data.get() + known->size);
            return {};
        }
        std::vector<uint64_t> chain;  // deltas from `hash` back, the last one's base held whole
        uint64_t at = hash;
        for (;;) {
            if (SharedBytes known = resolved.find(at)) {
                out->assign(known->data.get(), known->data.get() + known->size);
                break;
            }
            ContentsRecord c;
            ContentPlace place{};
            bool real = false;
            if (TraceError e = locate(at, may_evict_raw, &c, &place, &real)) return e;
            const size_t n = c.size();
            if (real) {
                out->assign(c.data(), c.data() + n);
                if (format::content_key(out->data(), n, c.seed, hash_bits) != at) {
                    return error(TraceErrorCode::kContentMismatch, place.chunk_offset,
                                 "contents " + hex(at) + " hold bytes that hash differently");
                }
                break;
            }
            auto base = contents.find(c.base_hash);
            if (base == contents.end() ||
                !precedes(base->second.chunk_offset, base->second.raw_offset, place.chunk_offset,
                          place.raw_offset)) {
                return error(TraceErrorCode::kMissingContents, place.chunk_offset,
                             "delta contents " + hex(at) + " (raw offset " +
                                 std::to_string(place.raw_offset) + ") name the base " +
                                 hex(c.base_hash) + ", which no earlier record defines");
            }
            if (base->second.size != n) {
                return error(TraceErrorCode::kContentMismatch, place.chunk_offset,
                             "delta contents " + hex(at) + " hold " + std::to_string(n) +
                                 " bytes but their base " + hex(c.base_hash) + " holds " +
                                 std::to_string(base->second.size));
            }
            chain.push_back(at);
            at = c.base_hash;
        }
        for (size_t k = chain.size(); k-- > 0;) {
            ContentsRecord c;
            ContentPlace place{};
            bool real = false;
            if (TraceError e = locate(chain[k], may_evict_raw, &c, &place, &real)) return e;
            if (real) {  // decoded meanwhile (cannot happen today): its bytes are the answer
                out->assign(c.data(), c.data() + c.size());
                continue;
            }
            const size_t n = c.size();
            if (n != out->size()) {
                return error(TraceErrorCode::kContentMismatch, place.chunk_offset,
                             "delta contents " + hex(chain[k]) + " changed size while read");
            }
            apply_delta(c.data(), c.byte_planes, out->data(), n, out->data());
            if (format::content_key(out->data(), n, c.seed, hash_bits) != chain[k]) {
                return error(TraceErrorCode::kContentMismatch, place.chunk_offset,
                             "delta contents " + hex(chain[k]) +
                                 " decode to bytes that hash differently (a damaged base?)");
            }
            keep_real_bytes(chain[k], out->data(), n, nullptr);
        }
        return {};
    }

    TraceError read_contents(uint64_t hash, std::vector<uint8_t>* out) {
        return resolve_contents(hash, out, true);
    }

    // File header, trace header and (if intact) trailer + index. Fatal problems only
    // for what makes the file unreadable; the rest is damage.
    TraceError open() {
        size = src->size();
        stats.file_size = size;
        raw_budget = options.max_raw_bytes ? options.max_raw_bytes : default_raw_budget(size);
        stats.raw_budget = raw_budget;
        if (size == 0) return error(TraceErrorCode::kTruncated, 0, "empty file");
        if (size < format::kFileHeaderSize) {
            if (size >= 8 && std::memcmp(read_small(0, 8).data(), format::kFileMagic, 8) != 0) {
                return error(TraceErrorCode::kNotATrace, 0, "not a clastrace trace (wrong magic)");
            }
            return error(TraceErrorCode::kTruncated, size,
                         "file of " + std::to_string(size) +
                             " bytes is shorter than the 32-byte file header");
        }
        format::FileHeader fh{};
        if (!src->read_at(0, sizeof fh, reinterpret_cast<uint8_t*>(&fh))) {
            return error(TraceErrorCode::kIoError, 0, "read failed: " + src->last_error());
        }
        if (std::memcmp(fh.magic, format::kFileMagic, 8) != 0) {
            return error(TraceErrorCode::kNotATrace, 0, "not a clastrace trace (wrong magic)");
        }
        version_major = fh.version_major;
        version_minor = fh.version_minor;
        if (fh.version_major != format::kVersionMajor) {
            return error(TraceErrorCode::kUnsupportedVersion,
                         offsetof(format::FileHeader, version_major),
                         "format version " + std::to_string(fh.version_major) + "." +
                             std::to_string(fh.version_minor) +
                             " is not supported (this reader reads " +
                             std::to_string(format::kVersionMajor) + ".x)");
        }
        if (fh.trace_header_size > format::kMaxTraceHeaderBytes ||
            fh.trace_header_size > size - format::kFileHeaderSize) {
            report(TraceErrorCode::kLengthOutOfRange,
                   offsetof(format::FileHeader, trace_header_size),
                   "trace header claims " + std::to_string(fh.trace_header_size) +
                       " bytes (limit " + std::to_string(format::kMaxTraceHeaderBytes) +
                       ", file has " + std::to_string(size - format::kFileHeaderSize) +
                       " after the file header)");
            data_start = format::kFileHeaderSize;
            restart_at(data_start);
            resync(data_start);
        } else {
            header_bytes.resize(fh.trace_header_size);
            if (!src->read_at(format::kFileHeaderSize, header_bytes.size(), header_bytes.data())) {
                return error(TraceErrorCode::kIoError, format::kFileHeaderSize,
                             "read failed: " + src->last_error());
            }
            data_start = format::kFileHeaderSize + format::align8(fh.trace_header_size);
            // The padding to 8 bytes is outside every checksum, so it must be zero.
            uint64_t pad_at = format::kFileHeaderSize + fh.trace_header_size;
            if (data_start <= size) {
                std::vector<uint8_t> pad =
                    read_small(pad_at, static_cast<size_t>(data_start - pad_at));
                if (std::any_of(pad.begin(), pad.end(), [](uint8_t b) { return b != 0; })) {
                    report(TraceErrorCode::kBadChunk, pad_at,
                           "non-zero padding after the trace header");
                }
            }
            uint64_t computed =
                format::file_header_checksum(fh, header_bytes.data(), header_bytes.size());
            if (computed != fh.checksum) {
                report(TraceErrorCode::kChecksumMismatch, offsetof(format::FileHeader, checksum),
                       "file header checksum mismatch (stored " + hex(fh.checksum) + ", computed " +
                           hex(computed) + ")");
            } else {
                flatbuffers::Verifier verifier(header_bytes.data(), header_bytes.size(), 64,
                                               1'000'000);
                if (!verifier.VerifyBuffer<fbs::TraceHeader>(nullptr)) {
                    report(TraceErrorCode::kInvalidRecord, format::kFileHeaderSize,
                           "trace header fails the FlatBuffers verifier");
                } else {
                    header = flatbuffers::GetRoot<fbs::TraceHeader>(header_bytes.data());
                    if (header->capture()) {
                        unsigned bits = header->capture()->content_hash_bits();
                        if (bits >= 1 && bits <= 64) hash_bits = bits;
                    }
                }
            }
            restart_at(data_start);
        }
        full_scan = true;
        open_index();
        return {};
    }

    std::vector<uint8_t> read_small(uint64_t at, size_t n) {
        std::vector<uint8_t> v(n);
        if (!src->read_at(at, n, v.data())) v.assign(n, 0);
        return v;
    }

    void open_index() {
        if (size < data_start + format::kTrailerSize) {
            report(TraceErrorCode::kTruncated, size,
                   "no trailer: the file was cut or its writer never finished");
            return;
        }
        const uint64_t trailer_at = size - format::kTrailerSize;
        format::Trailer t{};
        if (!src->read_at(trailer_at, sizeof t, reinterpret_cast<uint8_t*>(&t))) return;
        if (std::memcmp(t.magic, format::kTrailerMagic, 8) != 0) {
            report(TraceErrorCode::kTruncated, size,
                   "no trailer at the end of the file: it was cut or its writer never finished");
            return;
        }
        uint64_t computed = format::trailer_checksum(t);
        if (computed != t.checksum) {
            report(TraceErrorCode::kBadIndex, trailer_at,
                   "trailer checksum mismatch (stored " + hex(t.checksum) + ", computed " +
                       hex(computed) + ")");
            return;
        }
        if (t.trailer_offset != trailer_at || t.index_offset < data_start ||
            t.index_offset >
                trailer_at - std::min<uint64_t>(trailer_at, format::kChunkHeaderSize)) {
            report(TraceErrorCode::kBadIndex, trailer_at, "trailer points outside the file");
            return;
        }
        format::ChunkHeader h{};
        TraceError err;
        if (read_chunk(t.index_offset, &h, &index_raw, &err) != ChunkStatus::kOk) {
            err.code =
                err.code == TraceErrorCode::kTruncated ? TraceErrorCode::kBadIndex : err.code;
            err.message += " (index chunk)";
            report(std::move(err));
            return;
        }
        if (h.kind != static_cast<uint16_t>(format::ChunkKind::kIndex) ||
            t.index_offset + format::kChunkHeaderSize + h.compressed_size != trailer_at) {
            report(TraceErrorCode::kBadIndex, t.index_offset,
                   "trailer does not point at the index chunk");
            return;
        }
        flatbuffers::Verifier verifier(index_raw.data(), index_raw.size(), 64, 10'000'000);
        if (!verifier.VerifyBuffer<fbs::TraceIndex>(nullptr)) {
            report(TraceErrorCode::kBadIndex, t.index_offset,
                   "index fails the FlatBuffers verifier");
            return;
        }
        const auto* idx = flatbuffers::GetRoot<fbs::TraceIndex>(index_raw.data());
        if (!idx->chunks()) {
            report(TraceErrorCode::kBadIndex, t.index_offset, "index lists no chunks");
            return;
        }
        // The index chunk's own header must agree with what it indexes.
        if (h.record_count != 0 || h.first_submission != idx->submission_count() ||
            h.chunk_number != idx->chunks()->size()) {
            report(TraceErrorCode::kBadIndex, t.index_offset,
                   "index chunk header disagrees with the index (record count " +
                       std::to_string(h.record_count) + ", first submission " +
                       std::to_string(h.first_submission) + ", chunk number " +
                       std::to_string(h.chunk_number) + ")");
            return;
        }
        index = idx;
        index_offset = t.index_offset;
        check_index_entries();
        if (const auto* places = index->contents()) {
            const auto* chunks = index->chunks();
            contents.reserve(places->size());
            bool reported = false;
            for (const fbs::ContentLocation* c : *places) {
                if (c->chunk() >= chunks->size()) {
                    if (!reported) {
                        report(TraceErrorCode::kBadIndex, index_offset,
                               "index places contents " + hex(c->hash()) + " in chunk " +
                                   std::to_string(c->chunk()) + ", it lists " +
                                   std::to_string(chunks->size()) + " chunks");
                    }
                    reported = true;
                    continue;
                }
                contents.emplace(c->hash(),
                                 ContentPlace{c->size(), chunks->Get(c->chunk())->file_offset(),
                                              c->raw_offset(), false});
            }
        }
        CLASTRACE_DEBUG_ASSERT(chunk_index_holds());
    }

    // The index's chunk list on its own: offsets rising inside the records, each chunk
    // starting where the submissions before it end, totals the sum of the entries. The
    // scan then compares each entry with the chunk at its offset.
    void check_index_entries() {
        const auto* chunks = index->chunks();
        index_position.reserve(chunks->size());
        index_chunk_read.assign(chunks->size(), false);
        uint64_t records = 0;
        uint64_t submissions = 0;
        uint64_t previous_end = data_start;
        std::string problem;
        for (uint32_t i = 0; i < chunks->size(); ++i) {
            const fbs::ChunkLocation* c = chunks->Get(i);
            if (problem.empty() &&
                (c->file_offset() < previous_end || c->file_offset() >= index_offset)) {
                problem = "entry " + std::to_string(i) + " places a chunk at offset " +
                          std::to_string(c->file_offset()) + ", outside the records after offset " +
                          std::to_string(previous_end);
            }
            if (problem.empty() && c->first_submission() != submissions) {
                problem = "entry " + std::to_string(i) + " starts at submission " +
                          std::to_string(c->first_submission()) + " after " +
                          std::to_string(submissions) + " submissions";
            }
            previous_end = c->file_offset() + format::kChunkHeaderSize + c->compressed_size();
            records += c->record_count();
            submissions += c->submission_count();
            index_position.emplace(c->file_offset(), i);
        }
        if (problem.empty() &&
            (records != index->record_count() || submissions != index->submission_count())) {
            problem = "its chunks hold " + std::to_string(records) + " records and " +
                      std::to_string(submissions) + " submissions, its totals say " +
                      std::to_string(index->record_count()) + " and " +
                      std::to_string(index->submission_count());
        }
        if (!problem.empty()) report(TraceErrorCode::kBadIndex, index_offset, "index: " + problem);
    }

    // The reader's lookup of the index, whatever the file says: one read flag per entry, and
    // each offset leads to an entry placing a chunk at that offset (a hostile index listing
    // an offset twice keeps its first entry). Contents placed by the index lie in a listed chunk.
    bool chunk_index_holds() const {
        const auto* chunks = index->chunks();
        if (index_chunk_read.size() != chunks->size() || index_position.size() > chunks->size())
            return false;
        for (const auto& [offset, place] : index_position)
            if (place >= chunks->size() || chunks->Get(place)->file_offset() != offset)
                return false;
        for (const auto& [hash, place] : contents)
            if (!place.seen_in_scan && !index_position.contains(place.chunk_offset)) return false;
        return true;
    }
};

uint64_t default_raw_budget(uint64_t file_size) {
    const uint64_t relative = file_size > UINT64_MAX / kRawBudgetPerFileByte
                                  ? UINT64_MAX
                                  : file_size * kRawBudgetPerFileByte;
    return std::max(kRawBudgetFloorBytes, relative);
}

TraceReader::TraceReader(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
TraceReader::~TraceReader() = default;

static std::unique_ptr<TraceReader::Impl> make_impl(std::unique_ptr<ByteSource> src,
                                                    const std::string& name,
                                                    const TraceReaderOptions& options) {
    auto impl = std::make_unique<TraceReader::Impl>();
    impl->options = options;
    impl->src = std::move(src);
    impl->name = name;
    return impl;
}

std::unique_ptr<TraceReader> TraceReader::open(const std::string& path, TraceError* error,
                                               const TraceReaderOptions& options) {
    std::string why;
    auto src = open_file_source(path, &why);
    if (!src) {
        *error = make_trace_error(TraceErrorCode::kIoError, path, 0, "cannot open: " + why);
        return nullptr;
    }
    auto impl = make_impl(std::move(src), path, options);
    if (TraceError e = impl->open()) {
        *error = std::move(e);
        return nullptr;
    }
    return std::unique_ptr<TraceReader>(new TraceReader(std::move(impl)));
}

std::unique_ptr<TraceReader> TraceReader::open_memory(const uint8_t* data, size_t size,
                                                      const std::string& name, TraceError* error,
                                                      const TraceReaderOptions& options) {
    auto impl = make_impl(memory_source(data, size), name, options);
    if (TraceError e = impl->open()) {
        *error = std::move(e);
        return nullptr;
    }
    return std::unique_ptr<TraceReader>(new TraceReader(std::move(impl)));
}

uint16_t TraceReader::version_major() const { return impl_->version_major; }
uint16_t TraceReader::version_minor() const { return impl_->version_minor; }
uint16_t TraceReader::current_version_minor() { return format::kVersionMinor; }
const fbs::TraceHeader* TraceReader::header() const { return impl_->header; }
bool TraceReader::has_index() const { return impl_->index != nullptr; }
uint64_t TraceReader::indexed_submission_count() const {
    return impl_->index ? impl_->index->submission_count() : 0;
}
bool TraceReader::next(RecordView* out) { return impl_->next(out); }
TraceError TraceReader::seek_to_submission(uint64_t k) { return impl_->seek(k); }
TraceError TraceReader::read_contents(uint64_t hash, std::vector<uint8_t>* out) {
    return impl_->read_contents(hash, out);
}
const std::vector<TraceError>& TraceReader::damage() const { return impl_->damage; }
uint64_t TraceReader::damage_count() const { return impl_->damage_total; }
const TraceReadStats& TraceReader::stats() const {
    impl_->stats.raw_bytes_decompressed = impl_->raw_spent.load();
    impl_->stats.chunk_buffer_bytes = impl_->chunk_buffer_bytes();
    impl_->stats.real_bytes_allocated = impl_->pool->allocated_bytes();
    return impl_->stats;
}

}  // namespace clastrace::traces
