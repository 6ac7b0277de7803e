// SPDX-License-Identifier: Apache-2.0
#include <clastrace/traces/trace_writer.h>

#include <clastrace/traces/records.h>

#include "byte_planes.h"
#include "chunk_streams.h"
#include "file_format.h"

#include <cerrno>
#include <chrono>
#include <condition_variable>
#include <ctime>
#include <cstring>
#include <deque>
#include <fcntl.h>
#include <list>
#include <mutex>
#include <span>
#include <pthread.h>
#include <sched.h>
#include <sys/resource.h>
#include <sys/uio.h>
#include <thread>
#include <unistd.h>
#include <unordered_map>
#include <vector>

#define XXH_INLINE_ALL
#include <xxhash.h>
#include <zstd.h>

#include "content_hash.h"
#include "clastrace/traces/output_file.h"
#include "stored_text.h"

namespace clastrace::traces {

namespace {

// The chunk being filled, already split in the two streams of a streams payload
// (chunk_streams.h), so the compression thread compresses them as they are. With
// content_streams off every byte is in `records` and there are no cuts.
struct ChunkBuffers {
    format::UninitializedBytes records;   // the raw bytes with the contents' bytes cut out
    format::UninitializedBytes contents;  // those bytes, in cut order, each in its layout
    std::vector<format::ContentCut> cuts;
    size_t raw_size() const { return records.size() + contents.size(); }
    format::SplitChunk split() const { return {records, contents, cuts}; }
    void clear() {
        records.clear();
        contents.clear();
        cuts.clear();
    }
};

// One compressing thread's zstd context and buffers (the writer's worker; finish() for the
// index).
struct Compressor {
    ZSTD_CCtx* cctx = ZSTD_createCCtx();
    format::UninitializedBytes payload;  // the chunk's compressed payload
    format::UninitializedBytes joined;   // the raw bytes of a chunk written as one frame after all
    Compressor() = default;
    Compressor(const Compressor&) = delete;
    Compressor& operator=(const Compressor&) = delete;
    ~Compressor() { ZSTD_freeCCtx(cctx); }
};

// A sealed chunk on its way to the compression thread.
struct PendingChunk {
    ChunkBuffers bytes;
    uint32_t chunk_number = 0;
    uint32_t record_count = 0;
    uint32_t submission_count = 0;
    uint64_t first_submission = 0;
};

// What the writer remembers of each distinct content to answer later add_contents
// calls: its size and a 128-bit fingerprint standing in for the bytes themselves
// (keeping bytes would make memory grow with the trace). Equal size + equal 128-bit
// fingerprint is taken as equal bytes.
struct StoredContents {
    uint64_t size;
    XXH128_hash_t fingerprint;
    uint32_t chain_depth;  // deltas between these contents and contents stored whole
};

// The place a snapshot was taken: its contents there are the base of the next contents there.
struct SnapshotRange {
    uint64_t buffer, offset, address, size;
    bool operator==(const SnapshotRange&) const = default;
};
struct SnapshotRangeHash {
    size_t operator()(const SnapshotRange& r) const {
        return static_cast<size_t>((r.buffer * 0x9E3779B97F4A7C15ull) ^ r.offset ^
                                   (r.address * 0xC2B2AE3D27D4EB4Full) ^ (r.size << 17));
    }
};

// The last contents of one range, whole, for the delta of its next contents.
struct RangeBase {
    uint64_t hash = 0;
    uint32_t chain_depth = 0;
    std::vector<uint8_t> bytes;
    std::list<SnapshotRange>::iterator recency;  // its place in DeltaBases::by_recency
};

// Ranges' last contents, the least recently used forgotten first past the byte budget.
struct DeltaBases {
    std::unordered_map<SnapshotRange, RangeBase, SnapshotRangeHash> by_range;
    std::list<SnapshotRange> by_recency;  // front: least recently used
    uint64_t bytes_held = 0;

    RangeBase* find(const SnapshotRange& range) {
        auto it = by_range.find(range);
        if (it == by_range.end()) return nullptr;
        by_recency.splice(by_recency.end(), by_recency, it->second.recency);
        return &it->second;
    }

    // Keeps `pieces` as the range's last contents `hash`, within `budget` bytes in all.
    void remember(const SnapshotRange& range, uint64_t hash, uint32_t chain_depth,
                  std::span<const ContentPiece> pieces, uint64_t budget) {
        RangeBase* base = find(range);
        if (base && base->hash == hash) return;
        if (!base) {
            if (range.size > budget / 4) return;  // one range may not crowd out the others
            while (bytes_held + range.size > budget && !by_recency.empty()) forget_oldest();
            base = &by_range[range];
            base->recency = by_recency.insert(by_recency.end(), range);
            base->bytes.resize(range.size);
            bytes_held += range.size;
        }
        base->hash = hash;
        base->chain_depth = chain_depth;
        uint8_t* to = base->bytes.data();
        for (const ContentPiece& p : pieces) {
            if (p.size) std::memcpy(to, p.bytes, p.size);
            to += p.size;
        }
    }

    void forget_oldest() {
        auto it = by_range.find(by_recency.front());
        bytes_held -= it->second.bytes.size();
        by_range.erase(it);
        by_recency.pop_front();
    }
};

// Writes `pieces` XOR `base` (of the same total size) to `to`.
void xor_pieces(std::span<const ContentPiece> pieces, const uint8_t* base, uint8_t* to) {
    for (const ContentPiece& p : pieces) {
        const auto* from = static_cast<const uint8_t*>(p.bytes);
        for (size_t i = 0; i < p.size; ++i) to[i] = from[i] ^ base[i];
        to += p.size;
        base += p.size;
    }
}

uint64_t now_ns() {
    return uint64_t(std::chrono::duration_cast<std::chrono::nanoseconds>(
                        std::chrono::steady_clock::now().time_since_epoch())
                        .count());
}

uint64_t thread_cpu_ns() {
    timespec t{};
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
    return uint64_t(t.tv_sec) * 1000000000ull + uint64_t(t.tv_nsec);
}

// Size and fingerprint of stored contents, to find a repeat's key (a seeded XXH3-64 fixed by
// the format) by the fingerprint alone.
struct Fingerprint {
    uint64_t low, high, size;
    bool operator==(const Fingerprint&) const = default;
};
struct FingerprintHash {
    size_t operator()(const Fingerprint& f) const {
        return static_cast<size_t>(f.low ^ (f.size * 0x9E3779B97F4A7C15ull));
    }
};

struct ContentPlace {
    uint64_t hash;
    uint64_t size;
    uint32_t chunk;
    uint32_t raw_offset;
};

}  // namespace

struct TraceWriter::Impl {
    std::string path;
    int fd = -1;
    TraceWriterOptions options;
    bool finished = false;

    // Main-thread state: the chunk being filled.
    ChunkBuffers filling;
    uint32_t raw_records = 0;
    uint32_t raw_submissions = 0;
    uint64_t chunk_first_submission = 0;
    uint32_t next_chunk_number = 0;
    uint64_t submissions = 0;
    uint64_t records = 0;
    flatbuffers::FlatBufferBuilder fbb{1024};
    std::unordered_map<uint64_t, StoredContents> contents;
    std::unordered_map<Fingerprint, uint64_t, FingerprintHash> keys_by_fingerprint;
    std::vector<ContentPlace> content_places;
    DeltaBases delta_bases;
    std::vector<uint8_t> gathered;  // contents in pieces gathered before byte planes
    TraceWriterStats counters;      // main-thread counters (chunk/bytes come from the worker)

    // Shared with the compression threads, under `mutex`.
    std::mutex mutex;
    std::condition_variable queue_changed;  // also: a chunk was written, a worker is idle
    std::deque<PendingChunk> queue;
    std::vector<ChunkBuffers> spare_buffers;  // recycled chunk buffers
    uint32_t busy_workers = 0;                // workers holding a chunk taken from the queue
    uint32_t next_to_write = 0;               // chunks are written in their order: this one's turn
    bool stop = false;
    TraceError error;          // first error; sticky
    uint64_t file_offset = 0;  // next byte a worker writes
    std::vector<fbs::ChunkLocation> chunk_locations;
    uint64_t compressed_bytes = 0;
    uint64_t raw_bytes = 0;
    uint64_t compressor_cpu_ns = 0, flush_wait_ns = 0;
    std::vector<std::thread> workers;

    TraceError fail_io(const char* what, int err, uint64_t offset) {
        return make_trace_error(TraceErrorCode::kIoError, path, offset,
                                std::string(what) + " failed: " + std::strerror(err));
    }

    // Writes all bytes or reports the errno (ENOSPC, EIO, ...) naming the offset.
    TraceError write_all(const iovec* parts, int count, uint64_t offset) {
        std::vector<iovec> iov(parts, parts + count);
        size_t index = 0;
        for (;;) {
            while (index < iov.size() && iov[index].iov_len == 0) ++index;
            if (index == iov.size()) break;
            ssize_t n = ::writev(fd, iov.data() + index, static_cast<int>(iov.size() - index));
            if (n < 0 && errno == EINTR) continue;
            if (n < 0) return fail_io("write", errno, offset);
            if (n == 0) return fail_io("write", EIO, offset);
            offset += static_cast<uint64_t>(n);
            size_t left = static_cast<size_t>(n);
            while (left > 0 && index < iov.size()) {
                if (left >= iov[index].iov_len) {
                    left -= iov[index].iov_len;
                    ++index;
                } else {
                    iov[index].iov_base = static_cast<uint8_t*>(iov[index].iov_base) + left;
                    iov[index].iov_len -= left;
                    left = 0;
                }
            }
        }
        return {};
    }

    // Compresses one chunk into compressor.payload: a streams payload when it has contents (one
    // frame after all when that would pass one frame's bound), else one frame. Returns an empty
    // string or zstd's complaint.
    std::string compress_chunk(Compressor& compressor, const format::SplitChunk& chunk) {
        const uint64_t started = now_ns();
        format::UninitializedBytes& compressed = compressor.payload;
        const size_t size = chunk.raw_size();
        const int level = options.zstd_level, window_log = options.zstd_window_log;
        std::string problem;
        compressed.clear();
        if (!chunk.cuts.empty())
            problem =
                format::encode_split_chunk(compressor.cctx, chunk, level, window_log, &compressed);
        // Readers bound a payload by what one frame can take: past it (bytes that do not
        // compress, many small contents), the chunk is one frame after all.
        if (problem.empty() && !chunk.cuts.empty() &&
            compressed.size() > ZSTD_compressBound(size)) {
            format::join_split_chunk(chunk, &compressor.joined);
            compressed.clear();
            problem = format::compress_frame(compressor.cctx, compressor.joined.data(), size, level,
                                             window_log, &compressed);
        } else if (chunk.cuts.empty()) {
            problem = format::compress_frame(compressor.cctx, chunk.records.data(), size, level,
                                             window_log, &compressed);
        }
        std::lock_guard lock(timing_mutex);
        compress_ns += now_ns() - started;
        return problem;
    }

    // Writes the chunk header and compressor.payload (compress_chunk's) at `offset`.
    TraceError write_payload(const Compressor& compressor, format::ChunkKind kind,
                             uint32_t chunk_number, uint32_t record_count,
                             uint64_t first_submission, size_t raw_size, uint64_t offset) {
        const uint64_t started = now_ns();
        const format::UninitializedBytes& compressed = compressor.payload;
        format::ChunkHeader h =
            format::sealed_chunk_header(kind, chunk_number, record_count, first_submission,
                                        static_cast<uint32_t>(raw_size), compressed.data(),
                                        static_cast<uint32_t>(compressed.size()));
        iovec parts[2] = {{&h, sizeof h},
                          {const_cast<uint8_t*>(compressed.data()), compressed.size()}};
        TraceError e = write_all(parts, 2, offset);
        std::lock_guard lock(timing_mutex);
        file_write_ns += now_ns() - started;
        return e;
    }
    uint64_t compress_ns = 0, file_write_ns = 0;
    uint32_t compressors_placed = 0;
    std::mutex timing_mutex;  // the timing totals and placements above

    // Runs one compression thread with the options' priority and CPUs (best effort: without the
    // right to either the thread keeps the caller's).
    void place_worker() {
        sched_param idle{};
        const bool idled = options.compressor_idle_class &&
                           ::pthread_setschedparam(::pthread_self(), SCHED_IDLE, &idle) == 0;
        if (!idled && options.compressor_nice != 0)
            (void)::setpriority(PRIO_PROCESS, static_cast<id_t>(::gettid()),
                                options.compressor_nice);
        pthread_setname_np(pthread_self(), "clastrace-zstd");  // for profilers and top
        if (!options.compressor_cpus.empty()) {
            cpu_set_t cpus;
            CPU_ZERO(&cpus);
            for (unsigned c : options.compressor_cpus)
                if (c < CPU_SETSIZE) CPU_SET(c, &cpus);
            const bool placed = ::sched_setaffinity(0, sizeof cpus, &cpus) == 0;  // 0: this thread
            std::lock_guard placement(timing_mutex);
            compressors_placed += placed ? 1 : 0;
        }
    }

    // One compression thread: takes the next sealed chunk, compresses it while the other
    // threads compress the chunks after it, then waits for its turn to write, so chunks land in
    // the file in their order whatever thread finishes first.
    void worker_main() {
        place_worker();
        Compressor compressor;
        uint64_t cpu_counted = 0;
        std::unique_lock lock(mutex);
        for (;;) {
            queue_changed.wait(lock, [&] { return stop || !queue.empty(); });
            if (queue.empty()) break;  // stop requested and nothing left
            PendingChunk chunk = std::move(queue.front());
            queue.pop_front();
            ++busy_workers;
            const bool failed = static_cast<bool>(error);
            lock.unlock();
            queue_changed.notify_all();  // room in the queue for the caller's next chunk

            std::string problem;
            if (!failed) problem = compress_chunk(compressor, chunk.bytes.split());

            lock.lock();
            queue_changed.wait(lock, [&] { return next_to_write == chunk.chunk_number; });
            const uint64_t offset = file_offset;
            if (!error && !failed) {
                lock.unlock();
                TraceError e =
                    !problem.empty()
                        ? make_trace_error(TraceErrorCode::kIoError, path, offset, problem)
                        : write_payload(compressor, format::ChunkKind::kRecords, chunk.chunk_number,
                                        chunk.record_count, chunk.first_submission,
                                        chunk.bytes.raw_size(), offset);
                lock.lock();
                if (e && !error) error = std::move(e);
            }
            if (!error && !failed) {
                const uint32_t csize = static_cast<uint32_t>(compressor.payload.size());
                chunk_locations.push_back(
                    fbs::ChunkLocation(offset, chunk.first_submission, chunk.submission_count,
                                       chunk.record_count,
                                       static_cast<uint32_t>(chunk.bytes.raw_size()), csize));
                file_offset = offset + format::kChunkHeaderSize + csize;
                compressed_bytes += csize;
                raw_bytes += chunk.bytes.raw_size();
            }
            ++next_to_write;
            const uint64_t cpu = thread_cpu_ns();
            compressor_cpu_ns += cpu - cpu_counted;
            cpu_counted = cpu;
            chunk.bytes.clear();
            spare_buffers.push_back(std::move(chunk.bytes));
            --busy_workers;
            queue_changed.notify_all();
        }
        lock.unlock();
    }

    TraceError sticky_error() {
        std::lock_guard lock(mutex);
        return error;
    }

    // Hands the chunk being filled to the worker; blocks while too many are in flight.
    TraceError seal_chunk() {
        if (filling.raw_size() == 0) return sticky_error();
        PendingChunk chunk;
        chunk.bytes = std::move(filling);
        filling.clear();
        chunk.chunk_number = next_chunk_number++;
        chunk.record_count = raw_records;
        chunk.submission_count = raw_submissions;
        chunk.first_submission = chunk_first_submission;
        raw_records = 0;
        raw_submissions = 0;
        chunk_first_submission = submissions;
        ++counters.chunks;
        std::unique_lock lock(mutex);
        if (queue.size() >= options.max_chunks_in_flight && !error) {
            const uint64_t started = now_ns();
            queue_changed.wait(lock, [&] {
                return queue.size() < options.max_chunks_in_flight || error;
            });
            counters.append_blocked_ns += now_ns() - started;
        }
        if (error) return error;
        queue.push_back(std::move(chunk));
        if (!spare_buffers.empty()) {
            filling = std::move(spare_buffers.back());
            spare_buffers.pop_back();
        }
        queue_changed.notify_all();
        return {};
    }

    // Seals the chunk being filled when a record framed in `framed` bytes would take it past
    // chunk_raw_bytes (a record bigger than that gets a chunk of its own).
    TraceError make_room(size_t record_size) {
        if (record_size > format::kMaxRecordBytes) {
            return make_trace_error(TraceErrorCode::kInvalidArgument, path, 0,
                                    "record of " + std::to_string(record_size) +
                                        " bytes exceeds the " +
                                        std::to_string(format::kMaxRecordBytes) +
                                        "-byte record limit");
        }
        const size_t framed = format::kRecordFrameSize + format::align8(record_size);
        const size_t raw_size = filling.raw_size();
        if (raw_size != 0 && raw_size + framed > options.chunk_raw_bytes) return seal_chunk();
        return {};
    }

    // Room for `size` more bytes at the end of `to` (a recycled buffer keeps its capacity).
    static uint8_t* grow(format::UninitializedBytes& to, size_t size) {
        const size_t at = to.size();
        to.resize(at + size);
        return to.data() + at;
    }

    // Counts the record just framed.
    void count_record(fbs::RecordBody kind) {
        ++raw_records;
        ++records;
        if (kind == fbs::RecordBody::QueueSubmit) {
            ++raw_submissions;
            ++submissions;
        }
    }

    // Frames one verified Record FlatBuffer into the current chunk.
    TraceError add_frame(const uint8_t* data, size_t size, fbs::RecordBody kind) {
        if (TraceError e = make_room(size)) return e;
        const uint32_t frame[2] = {static_cast<uint32_t>(size), static_cast<uint32_t>(kind)};
        const size_t framed = format::kRecordFrameSize + format::align8(size);
        uint8_t* to = grow(filling.records, framed);
        std::memcpy(to, frame, sizeof frame);
        std::memcpy(to + format::kRecordFrameSize, data, size);
        std::memset(to + format::kRecordFrameSize + size, 0,
                    framed - format::kRecordFrameSize - size);
        count_record(kind);
        return {};
    }

    TraceError check_usable() {
        if (finished) {
            return make_trace_error(TraceErrorCode::kInvalidArgument, path, 0,
                                    "writer already finished");
        }
        return sticky_error();
    }

    TraceError append_bytes(const uint8_t* data, size_t size, bool allow_contents) {
        if (TraceError e = check_usable()) return e;
        flatbuffers::Verifier verifier(data, size, 128, 100'000'000);
        if (!fbs::VerifyRecordBuffer(verifier)) {
            return make_trace_error(TraceErrorCode::kInvalidArgument, path, 0,
                                    "record fails the FlatBuffers verifier");
        }
        const fbs::Record* record = fbs::GetRecord(data);
        fbs::RecordBody kind = record->body_type();
        if (kind == fbs::RecordBody::NONE) {
            return make_trace_error(TraceErrorCode::kInvalidArgument, path, 0,
                                    "record has no body");
        }
        if ((kind == fbs::RecordBody::MemoryContents ||
             kind == fbs::RecordBody::MemoryContentsDelta) &&
            !allow_contents) {
            return make_trace_error(TraceErrorCode::kInvalidArgument, path, 0,
                                    std::string(record_kind_name(kind)) +
                                        " records are written by add_contents, which "
                                        "deduplicates them");
        }
        if (kind == fbs::RecordBody::QueueSubmit &&
            record->body_as_QueueSubmit()->submission_index() != submissions) {
            return make_trace_error(TraceErrorCode::kInvalidArgument, path, 0,
                                    "QueueSubmit.submission_index " +
                                        std::to_string(
                                            record->body_as_QueueSubmit()->submission_index()) +
                                        " but the next submission is " +
                                        std::to_string(submissions));
        }
        if (has_invalid_utf8(*record)) return add_repaired_frame(*record, kind);
        return add_frame(data, size, kind);
    }

    // A record whose strings are not all UTF-8 is stored with them repaired (stored_text.h).
    TraceError add_repaired_frame(const fbs::Record& record, fbs::RecordBody kind) {
        fbs::RecordT repaired;
        record.UnPackTo(&repaired);
        make_strings_valid_utf8(repaired);
        flatbuffers::FlatBufferBuilder b(1024);
        b.Finish(fbs::Record::Pack(b, &repaired));
        return add_frame(b.GetBufferPointer(), b.GetSize(), kind);
    }

    TraceError finish() {
        if (finished) return check_usable();
        TraceError e = seal_chunk();
        {
            std::unique_lock lock(mutex);
            const uint64_t started = now_ns();
            queue_changed.wait(lock, [&] { return queue.empty() && busy_workers == 0; });
            flush_wait_ns += now_ns() - started;
            stop = true;
            queue_changed.notify_all();
        }
        for (std::thread& worker : workers) worker.join();
        workers.clear();
        finished = true;
        if (!e) e = sticky_error();
        if (!e) e = write_index();
        if (!e && options.sync_on_finish && ::fsync(fd) != 0 && errno != EINVAL && errno != EROFS) {
            e = fail_io("fsync", errno, file_offset);
        }
        if (::close(fd) != 0 && !e) e = fail_io("close", errno, file_offset);
        fd = -1;
        if (e) {
            std::lock_guard lock(mutex);
            if (!error) error = e;
        }
        return e;
    }

    TraceError write_index() {
        flatbuffers::FlatBufferBuilder b(1024 + chunk_locations.size() * 32 +
                                         content_places.size() * 24);
        std::vector<fbs::ContentLocation> places;
        places.reserve(content_places.size());
        for (const ContentPlace& p : content_places)
            places.emplace_back(p.hash, p.size, p.chunk, p.raw_offset);
        auto index = fbs::CreateTraceIndex(b, b.CreateVectorOfStructs(chunk_locations),
                                           b.CreateVectorOfStructs(places), records, submissions);
        b.Finish(index);
        Compressor compressor;
        const uint64_t index_offset = file_offset;
        const format::SplitChunk index_bytes{{b.GetBufferPointer(), b.GetSize()}, {}, {}};
        if (std::string problem = compress_chunk(compressor, index_bytes); !problem.empty())
            return make_trace_error(TraceErrorCode::kIoError, path, index_offset, problem);
        TraceError e = write_payload(compressor, format::ChunkKind::kIndex, next_chunk_number, 0,
                                     submissions, b.GetSize(), index_offset);
        if (e) return e;
        const uint32_t csize = static_cast<uint32_t>(compressor.payload.size());
        format::Trailer t =
            format::sealed_trailer(index_offset, index_offset + format::kChunkHeaderSize + csize);
        iovec part{&t, sizeof t};
        e = write_all(&part, 1, t.trailer_offset);
        if (!e) file_offset = t.trailer_offset + sizeof t;
        return e;
    }

    TraceError add_contents(std::span<const ContentPiece> pieces, uint64_t* hash,
                            const SnapshotRange* range);
    TraceError frame_contents(std::span<const ContentPiece> pieces, size_t size, uint64_t key,
                              uint64_t seed, const RangeBase* base);
    void frame_cut_contents(std::span<const ContentPiece> pieces, size_t size, fbs::RecordBody kind,
                            const RangeBase* base, bool planes);
    const uint8_t* contiguous(std::span<const ContentPiece> pieces, size_t size);

    void abandon() {
        if (!workers.empty()) {
            {
                std::lock_guard lock(mutex);
                stop = true;
                queue_changed.notify_all();
            }
            for (std::thread& worker : workers) worker.join();
            workers.clear();
        }
        if (fd >= 0) ::close(fd);
        fd = -1;
    }
};

namespace {

const char* options_problem(const TraceWriterOptions& options) {
    if (options.chunk_raw_bytes < 4096 || options.chunk_raw_bytes > format::kMaxChunkRawBytes) {
        return "chunk_raw_bytes must be in [4096, 256 MiB]";
    }
    if (options.max_chunks_in_flight == 0) return "max_chunks_in_flight must be >= 1";
    if (options.compressor_threads == 0 || options.compressor_threads > 64)
        return "compressor_threads must be in [1, 64]";
    if (options.content_hash_bits < 8 || options.content_hash_bits > 64)
        return "content_hash_bits must be in [8, 64]";
    if (options.zstd_level < ZSTD_minCLevel() || options.zstd_level > ZSTD_maxCLevel()) {
        return "zstd_level out of zstd's range";
    }
    if (options.zstd_window_log != 0 &&
        (options.zstd_window_log < 10 || options.zstd_window_log > 27))
        return "zstd_window_log must be 0 or in [10, 27]";
    return nullptr;
}

// An output refused or failed before any byte of the trace (its message names the path).
TraceError output_error(const std::string& problem) {
    TraceError e;
    e.code = TraceErrorCode::kIoError;
    e.message = problem;
    return e;
}

}  // namespace

TraceWriter::TraceWriter(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}

TraceWriter::~TraceWriter() {
    if (impl_) impl_->abandon();
}

std::unique_ptr<TraceWriter> TraceWriter::create(const std::string& path,
                                                 const fbs::TraceHeaderT& header,
                                                 const TraceWriterOptions& options,
                                                 TraceError* error) {
    if (const char* bad = options_problem(options)) {  // refused before the file is touched
        *error = make_trace_error(TraceErrorCode::kInvalidArgument, path, 0, bad);
        return nullptr;
    }
    OutputTarget target;
    std::string problem;
    const int fd = open_output_in_place(path, &target, &problem);
    if (fd < 0) {
        *error = output_error(problem);
        return nullptr;
    }
    return create_on(fd, path, header, options, error);
}

std::unique_ptr<TraceWriter> TraceWriter::create_on(int fd, const std::string& path,
                                                    const fbs::TraceHeaderT& header,
                                                    const TraceWriterOptions& options,
                                                    TraceError* error) {
    auto fail = [&](TraceErrorCode code,
                    const std::string& problem) -> std::unique_ptr<TraceWriter> {
        ::close(fd);
        *error = make_trace_error(code, path, 0, problem);
        return nullptr;
    };
    if (const char* problem = options_problem(options))
        return fail(TraceErrorCode::kInvalidArgument, problem);

    fbs::TraceHeaderT h = header;  // deep copy (object API) so the settings can be filled in
    if (!h.capture) h.capture = std::make_unique<fbs::CaptureSettingsT>();
    h.capture->chunk_raw_bytes = options.chunk_raw_bytes;
    h.capture->zstd_level = options.zstd_level;
    h.capture->content_hash_bits = static_cast<uint8_t>(options.content_hash_bits);
    make_strings_valid_utf8(h);
    flatbuffers::FlatBufferBuilder b;
    b.Finish(fbs::TraceHeader::Pack(b, &h));
    if (b.GetSize() > format::kMaxTraceHeaderBytes)
        return fail(TraceErrorCode::kInvalidArgument, "trace header over 16 MiB");

    std::string problem;
    if (!start_output_in_place(fd, path, &problem)) {
        ::close(fd);
        *error = output_error(problem);
        return nullptr;
    }

    auto impl = std::make_unique<Impl>();
    impl->path = path;
    impl->fd = fd;
    impl->options = options;

    format::FileHeader fh{};
    std::memcpy(fh.magic, format::kFileMagic, sizeof fh.magic);
    fh.version_major = format::kVersionMajor;
    fh.version_minor = format::kVersionMinor;
    fh.trace_header_size = b.GetSize();
    fh.checksum = format::file_header_checksum(fh, b.GetBufferPointer(), b.GetSize());
    static const uint8_t kZeros[8] = {};
    size_t pad = format::align8(b.GetSize()) - b.GetSize();
    iovec parts[3] = {{&fh, sizeof fh},
                      {b.GetBufferPointer(), b.GetSize()},
                      {const_cast<uint8_t*>(kZeros), pad}};
    if (TraceError e = impl->write_all(parts, 3, 0)) {
        *error = e;
        ::close(fd);
        impl->fd = -1;
        return nullptr;
    }
    impl->file_offset = sizeof fh + format::align8(b.GetSize());
    for (uint32_t i = 0; i < options.compressor_threads; ++i)
        impl->workers.emplace_back([p = impl.get()] { p->worker_main(); });
    return std::unique_ptr<TraceWriter>(new TraceWriter(std::move(impl)));
}

TraceError TraceWriter::add_contents(const void* bytes, size_t size, uint64_t* hash) {
    const ContentPiece one{bytes, size};
    return add_contents(std::span<const ContentPiece>(&one, 1), hash);
}

TraceError TraceWriter::add_contents(std::span<const ContentPiece> pieces, uint64_t* hash) {
    return impl_->add_contents(pieces, hash, nullptr);
}

// Keys `pieces` (a repeat returns the key it has) and, for new bytes, frames their record:
// whole, or XOR the last contents of `range` when the writer still holds them.
TraceError TraceWriter::Impl::add_contents(std::span<const ContentPiece> pieces, uint64_t* hash,
                                           const SnapshotRange* range) {
    Impl& w = *this;
    if (TraceError e = w.check_usable()) return e;
    size_t size = 0;
    for (const ContentPiece& p : pieces) size += p.size;
    if (size > format::kMaxRecordBytes - 128) {
        return make_trace_error(TraceErrorCode::kInvalidArgument, w.path, 0,
                                "contents of " + std::to_string(size) +
                                    " bytes exceed the per-record limit; snapshot it in parts");
    }
    struct Timed {  // add_contents's time, whichever way it returns
        uint64_t& total;
        uint64_t started = now_ns();
        ~Timed() { total += now_ns() - started; }
    } timed{w.counters.contents_ns};
    // A repeat (most snapshots of a frame loop) costs one hash pass over its pieces where they
    // lie; new contents then take one copy into their record. The pass gives both hashes: XXH3's
    // 64- and 128-bit variants share one streaming state (the 128-bit reset is the 64-bit one),
    // so the fingerprint and the seed-0 key are two digests of it.
    const ContentHashes hashes = hash_content(pieces.data(), pieces.size());
    const XXH128_hash_t fingerprint{hashes.fingerprint_low, hashes.fingerprint_high};
    const Fingerprint known{fingerprint.low64, fingerprint.high64, size};
    const bool deltas = range && options.delta_contents;
    auto repeat_of = [&](uint64_t key, const StoredContents& stored) -> TraceError {
        ++w.counters.contents_deduplicated;
        w.counters.contents_bytes_deduplicated += size;
        if (deltas)
            delta_bases.remember(*range, key, stored.chain_depth, pieces, options.delta_base_bytes);
        *hash = key;
        return {};
    };
    if (auto repeat = w.keys_by_fingerprint.find(known); repeat != w.keys_by_fingerprint.end())
        return repeat_of(repeat->second, w.contents.at(repeat->second));
    // New contents are keyed and framed straight from their pieces: no gathered copy.
    auto key_of = [&](uint64_t seed) {
        const unsigned bits = w.options.content_hash_bits;
        const uint64_t h =
            seed == 0 ? hashes.key_seed0 : content_key_of(pieces.data(), pieces.size(), seed);
        return bits >= 64
                   ? h
                   : (h & ((uint64_t{1} << bits) - 1));  // as format::content_key over the whole
    };
    // Seed 0 gives the key; a different byte string already holding that key (a real
    // collision) moves these bytes to the next seed until a free or matching key is found.
    for (uint64_t seed = 0;; ++seed) {
        uint64_t key = key_of(seed);
        auto [it, inserted] = w.contents.try_emplace(key, StoredContents{size, fingerprint, 0});
        if (!inserted) {
            if (it->second.size == size && XXH128_isEqual(it->second.fingerprint, fingerprint))
                return repeat_of(key, it->second);
            if (seed == 0) ++w.counters.hash_collisions;
            if (seed > 1'000'000) {
                return make_trace_error(TraceErrorCode::kInvalidArgument, w.path, 0,
                                        "no free content key left");
            }
            continue;
        }
        const RangeBase* base = deltas ? delta_bases.find(*range) : nullptr;
        if (base && options.delta_chain_limit && base->chain_depth >= options.delta_chain_limit)
            base = nullptr;
        if (TraceError e = frame_contents(pieces, size, key, seed, base)) {
            w.contents.erase(it);
            return e;
        }
        it->second.chain_depth = base ? base->chain_depth + 1 : 0;
        if (deltas)
            delta_bases.remember(*range, key, it->second.chain_depth, pieces,
                                 options.delta_base_bytes);
        w.keys_by_fingerprint.emplace(known, key);
        *hash = key;
        return {};
    }
}

// The bytes of `pieces` in one place: the only piece, or the pieces gathered into `gathered`.
const uint8_t* TraceWriter::Impl::contiguous(std::span<const ContentPiece> pieces, size_t size) {
    if (pieces.size() == 1) return static_cast<const uint8_t*>(pieces[0].bytes);
    gathered.resize(size);
    uint8_t* to = gathered.data();
    for (const ContentPiece& p : pieces) {
        if (p.size) std::memcpy(to, p.bytes, p.size);
        to += p.size;
    }
    return gathered.data();
}

namespace {

// Writes the `size` bytes a contents record of `pieces` holds to `to`: the bytes (no base), or
// XOR `base`'s, in byte planes when `planes` (from `gathered`, the pieces in one place).
void write_contents_bytes(std::span<const ContentPiece> pieces, const uint8_t* gathered,
                          size_t size, const RangeBase* base, bool planes, uint8_t* to) {
    if (base && planes) {
        format::xor_to_byte_planes(gathered, base->bytes.data(), size, to);
    } else if (base) {
        xor_pieces(pieces, base->bytes.data(), to);
    } else {
        for (const ContentPiece& p : pieces) {
            if (p.size) std::memcpy(to, p.bytes, p.size);
            to += p.size;
        }
    }
}

}  // namespace

// Frames the record of new bytes `key`: MemoryContents (whole), or MemoryContentsDelta (XOR
// `base`'s bytes, in byte planes when the options say so). With content_streams the record
// goes to the records stream without its bytes, which go straight to the contents stream.
TraceError TraceWriter::Impl::frame_contents(std::span<const ContentPiece> pieces, size_t size,
                                             uint64_t key, uint64_t seed, const RangeBase* base) {
    const bool cut = options.content_streams && size > 0;
    const bool planes = base && options.delta_byte_planes;
    fbb.Clear();
    uint8_t* vec_bytes = nullptr;
    auto vec = fbb.CreateUninitializedVector(size, &vec_bytes);
    if (!cut)  // (written before the tables: building them may move the buffer)
        write_contents_bytes(pieces, planes ? contiguous(pieces, size) : nullptr, size, base,
                             planes, vec_bytes);
    const fbs::RecordBody kind =
        base ? fbs::RecordBody::MemoryContentsDelta : fbs::RecordBody::MemoryContents;
    const flatbuffers::Offset<void> body =
        base ? fbs::CreateMemoryContentsDelta(fbb, key, seed, base->hash, vec, planes ? 4 : 0)
                   .Union()
             : fbs::CreateMemoryContents(fbb, key, seed, vec).Union();
    fbb.Finish(fbs::CreateRecord(fbb, kind, body));
    if (TraceError e = make_room(fbb.GetSize())) return e;
    content_places.push_back(
        {key, size, next_chunk_number, static_cast<uint32_t>(filling.raw_size())});
    if (cut) {
        frame_cut_contents(pieces, size, kind, base, planes);
    } else if (TraceError e = add_frame(fbb.GetBufferPointer(), fbb.GetSize(), kind)) {
        return e;
    }
    ++counters.contents_stored;
    counters.contents_bytes_stored += size;
    if (base) {
        ++counters.contents_delta_stored;
        counters.contents_delta_bytes += size;
    }
    return {};
}

// Frames the contents record built in fbb (its bytes not written) as a cut: the frame and the
// record around the bytes to the records stream, the bytes to the contents stream, whole
// contents that look like 32-bit integers in byte planes if the options say.
void TraceWriter::Impl::frame_cut_contents(std::span<const ContentPiece> pieces, size_t size,
                                           fbs::RecordBody kind, const RangeBase* base,
                                           bool planes) {
    const uint8_t* record = fbb.GetBufferPointer();
    const size_t record_size = fbb.GetSize();
    const fbs::Record* r = fbs::GetRecord(record);
    const size_t in_record =
        (base ? r->body_as_MemoryContentsDelta()->bytes() : r->body_as_MemoryContents()->bytes())
            ->data() -
        record;
    const size_t after = record_size - in_record - size;
    const size_t framed = format::kRecordFrameSize + format::align8(record_size);
    const uint32_t frame[2] = {static_cast<uint32_t>(record_size), static_cast<uint32_t>(kind)};
    const size_t frame_at = filling.raw_size();
    uint8_t* to = grow(filling.records, framed - size);
    std::memcpy(to, frame, sizeof frame);
    std::memcpy(to + format::kRecordFrameSize, record, in_record);
    to += format::kRecordFrameSize + in_record;
    std::memcpy(to, record + in_record + size, after);
    std::memset(to + after, 0, framed - format::kRecordFrameSize - record_size);

    format::CutLayout layout = format::CutLayout::kAsIs;
    const uint8_t* whole = nullptr;
    if (!base && options.whole_content_planes) {
        whole = contiguous(pieces, size);
        if (format::planes_pay(whole, size)) layout = format::CutLayout::kBytePlanes;
    }
    uint8_t* bytes = grow(filling.contents, size);
    if (layout == format::CutLayout::kBytePlanes)
        format::to_byte_planes(whole, size, bytes);
    else
        write_contents_bytes(pieces, planes ? contiguous(pieces, size) : nullptr, size, base,
                             planes, bytes);
    filling.cuts.push_back({static_cast<uint32_t>(frame_at + format::kRecordFrameSize + in_record),
                            static_cast<uint32_t>(size), layout});
    count_record(kind);
}

TraceError TraceWriter::snapshot(uint64_t buffer, uint64_t offset, uint64_t address,
                                 const void* bytes, size_t size, fbs::MemorySnapshot* out) {
    const ContentPiece one{bytes, size};
    return snapshot(buffer, offset, address, std::span<const ContentPiece>(&one, 1), out);
}

TraceError TraceWriter::snapshot(uint64_t buffer, uint64_t offset, uint64_t address,
                                 std::span<const ContentPiece> pieces, fbs::MemorySnapshot* out) {
    uint64_t size = 0;
    for (const ContentPiece& p : pieces) size += p.size;
    const SnapshotRange range{buffer, offset, address, size};
    uint64_t hash = 0;
    if (TraceError e = impl_->add_contents(pieces, &hash, &range)) return e;
    *out = fbs::MemorySnapshot(buffer, offset, address, size, hash);
    return {};
}

TraceError TraceWriter::append(const fbs::RecordT& record) {
    Impl& w = *impl_;
    w.fbb.Clear();
    w.fbb.Finish(fbs::Record::Pack(w.fbb, &record));
    return w.append_bytes(w.fbb.GetBufferPointer(), w.fbb.GetSize(), false);
}

TraceError TraceWriter::append(const fbs::Record* record) {
    fbs::RecordT copy;
    record->UnPackTo(&copy);
    return append(copy);
}

TraceError TraceWriter::append_record_bytes(const uint8_t* data, size_t size) {
    return impl_->append_bytes(data, size, false);
}

uint64_t TraceWriter::next_submission_index() const { return impl_->submissions; }

TraceError TraceWriter::flush() {
    Impl& w = *impl_;
    if (TraceError e = w.check_usable()) return e;
    if (TraceError e = w.seal_chunk()) return e;
    std::unique_lock lock(w.mutex);
    const uint64_t started = now_ns();
    w.queue_changed.wait(lock, [&] { return (w.queue.empty() && w.busy_workers == 0) || w.error; });
    w.flush_wait_ns += now_ns() - started;
    return w.error;
}

TraceError TraceWriter::finish() { return impl_->finish(); }

TraceWriterStats TraceWriter::stats() const {
    Impl& w = *impl_;
    TraceWriterStats s = w.counters;
    s.records = w.records;
    s.submissions = w.submissions;
    std::lock_guard lock(w.mutex);
    s.raw_bytes = w.raw_bytes;
    s.compressed_bytes = w.compressed_bytes;
    s.compressor_cpu_ns = w.compressor_cpu_ns;
    s.flush_wait_ns = w.flush_wait_ns;
    std::lock_guard timing(w.timing_mutex);
    s.compress_ns = w.compress_ns;
    s.file_write_ns = w.file_write_ns;
    s.compressor_placed = w.compressors_placed == w.options.compressor_threads;
    return s;
}

}  // namespace clastrace::traces
