// SPDX-License-Identifier: Apache-2.0
#include <clastrace/traces/trace_writer.h>

#include "file_format.h"

#include <cerrno>
#include <chrono>
#include <condition_variable>
#include <ctime>
#include <cstring>
#include <deque>
#include <fcntl.h>
#include <mutex>
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

// Bytes whose growth leaves new elements uninitialized: every framed record is written over
// whole (frame, body, padding), so value-initializing them first would be one more pass over
// each chunk.
template <class T>
struct UninitializedAllocator : std::allocator<T> {
    template <class U>
    struct rebind {
        using Other = UninitializedAllocator<U>;
    };
    template <class U>
    void construct(U* p) noexcept {
        ::new (static_cast<void*>(p)) U;
    }
    template <class U, class... Args>
    void construct(U* p, Args&&... args) {
        ::new (static_cast<void*>(p)) U(std::forward<Args>(args)...);
    }
};
using ChunkBytes = std::vector<uint8_t, UninitializedAllocator<uint8_t>>;

// A sealed chunk on its way to the compression thread.
struct PendingChunk {
    ChunkBytes raw;
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
};

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
    ChunkBytes raw;
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
    TraceWriterStats counters;  // main-thread counters (chunk/bytes come from the worker)

    // Shared with the compression thread, under `mutex`.
    std::mutex mutex;
    std::condition_variable queue_changed;
    std::deque<PendingChunk> queue;
    std::vector<ChunkBytes> spare_buffers;  // recycled raw buffers
    bool worker_busy = false;
    bool stop = false;
    TraceError error;          // first error; sticky
    uint64_t file_offset = 0;  // next byte the worker writes
    std::vector<fbs::ChunkLocation> chunk_locations;
    uint64_t compressed_bytes = 0;
    uint64_t raw_bytes = 0;
    uint64_t compress_ns = 0, file_write_ns = 0, compressor_cpu_ns = 0, flush_wait_ns = 0;
    std::thread worker;

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

    // Compresses and writes one chunk at file_offset; used by the worker and for the index.
    TraceError write_chunk(ZSTD_CCtx* cctx, std::vector<uint8_t>& compressed, const uint8_t* data,
                           size_t size, format::ChunkKind kind, uint32_t chunk_number,
                           uint32_t record_count, uint64_t first_submission, uint64_t offset,
                           uint32_t* compressed_size) {
        compressed.resize(ZSTD_compressBound(size));
        const uint64_t started = now_ns();
        size_t csize = ZSTD_compressCCtx(cctx, compressed.data(), compressed.size(), data, size,
                                         options.zstd_level);
        const uint64_t compressed_at = now_ns();
        if (ZSTD_isError(csize)) {
            return make_trace_error(TraceErrorCode::kIoError, path, offset,
                                    std::string("zstd compression failed: ") +
                                        ZSTD_getErrorName(csize));
        }
        format::ChunkHeader h =
            format::sealed_chunk_header(kind, chunk_number, record_count, first_submission,
                                        static_cast<uint32_t>(size), compressed.data(),
                                        static_cast<uint32_t>(csize));
        iovec parts[2] = {{&h, sizeof h}, {compressed.data(), csize}};
        *compressed_size = static_cast<uint32_t>(csize);
        TraceError e = write_all(parts, 2, offset);
        std::lock_guard lock(timing_mutex);
        compress_ns += compressed_at - started;
        file_write_ns += now_ns() - compressed_at;
        return e;
    }
    bool compressor_placed = false;
    std::mutex timing_mutex;  // the timing totals above and compressor_placed

    void worker_main() {
        // Best effort: without the right to either the thread keeps the caller's priority.
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
            compressor_placed = placed;
        }
        ZSTD_CCtx* cctx = ZSTD_createCCtx();
        std::vector<uint8_t> compressed;
        std::unique_lock lock(mutex);
        for (;;) {
            queue_changed.wait(lock, [&] { return stop || !queue.empty(); });
            if (queue.empty()) break;  // stop requested and nothing left
            PendingChunk chunk = std::move(queue.front());
            queue.pop_front();
            worker_busy = true;
            bool failed = static_cast<bool>(error);
            uint64_t offset = file_offset;
            lock.unlock();

            TraceError e;
            uint32_t csize = 0;
            if (!failed) {
                e = write_chunk(cctx, compressed, chunk.raw.data(), chunk.raw.size(),
                                format::ChunkKind::kRecords, chunk.chunk_number, chunk.record_count,
                                chunk.first_submission, offset, &csize);
            }

            lock.lock();
            compressor_cpu_ns = thread_cpu_ns();
            if (!failed && e) error = std::move(e);
            if (!failed && !error) {
                chunk_locations.push_back(
                    fbs::ChunkLocation(offset, chunk.first_submission, chunk.submission_count,
                                       chunk.record_count, static_cast<uint32_t>(chunk.raw.size()),
                                       csize));
                file_offset = offset + format::kChunkHeaderSize + csize;
                compressed_bytes += csize;
                raw_bytes += chunk.raw.size();
            }
            chunk.raw.clear();
            spare_buffers.push_back(std::move(chunk.raw));
            worker_busy = false;
            queue_changed.notify_all();
        }
        lock.unlock();
        ZSTD_freeCCtx(cctx);
    }

    TraceError sticky_error() {
        std::lock_guard lock(mutex);
        return error;
    }

    // Hands the chunk being filled to the worker; blocks while too many are in flight.
    TraceError seal_chunk() {
        if (raw.empty()) return sticky_error();
        PendingChunk chunk;
        chunk.raw = std::move(raw);
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
            raw = std::move(spare_buffers.back());
            spare_buffers.pop_back();
        }
        queue_changed.notify_all();
        return {};
    }

    // Frames one verified Record FlatBuffer into the current chunk.
    TraceError add_frame(const uint8_t* data, size_t size, fbs::RecordBody kind) {
        if (size > format::kMaxRecordBytes) {
            return make_trace_error(TraceErrorCode::kInvalidArgument, path, 0,
                                    "record of " + std::to_string(size) + " bytes exceeds the " +
                                        std::to_string(format::kMaxRecordBytes) +
                                        "-byte record limit");
        }
        size_t framed = format::kRecordFrameSize + format::align8(size);
        if (!raw.empty() && raw.size() + framed > options.chunk_raw_bytes) {
            if (TraceError e = seal_chunk()) return e;
        }
        if (raw.capacity() < options.chunk_raw_bytes) raw.reserve(options.chunk_raw_bytes);
        size_t at = raw.size();
        raw.resize(at + framed);
        uint32_t frame[2] = {static_cast<uint32_t>(size), static_cast<uint32_t>(kind)};
        std::memcpy(raw.data() + at, frame, sizeof frame);
        std::memcpy(raw.data() + at + format::kRecordFrameSize, data, size);
        std::memset(raw.data() + at + format::kRecordFrameSize + size, 0,
                    framed - format::kRecordFrameSize - size);
        ++raw_records;
        ++records;
        if (kind == fbs::RecordBody::QueueSubmit) {
            ++raw_submissions;
            ++submissions;
        }
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
        if (kind == fbs::RecordBody::MemoryContents && !allow_contents) {
            return make_trace_error(
                TraceErrorCode::kInvalidArgument, path, 0,
                "MemoryContents records are written by add_contents, which deduplicates them");
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
            queue_changed.wait(lock, [&] { return (queue.empty() && !worker_busy); });
            flush_wait_ns += now_ns() - started;
            stop = true;
            queue_changed.notify_all();
        }
        worker.join();
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
        ZSTD_CCtx* cctx = ZSTD_createCCtx();
        std::vector<uint8_t> compressed;
        uint32_t csize = 0;
        uint64_t index_offset = file_offset;
        TraceError e = write_chunk(cctx, compressed, b.GetBufferPointer(), b.GetSize(),
                                   format::ChunkKind::kIndex, next_chunk_number, 0, submissions,
                                   index_offset, &csize);
        ZSTD_freeCCtx(cctx);
        if (e) return e;
        format::Trailer t =
            format::sealed_trailer(index_offset, index_offset + format::kChunkHeaderSize + csize);
        iovec part{&t, sizeof t};
        e = write_all(&part, 1, t.trailer_offset);
        if (!e) file_offset = t.trailer_offset + sizeof t;
        return e;
    }

    void abandon() {
        if (worker.joinable()) {
            {
                std::lock_guard lock(mutex);
                stop = true;
                queue_changed.notify_all();
            }
            worker.join();
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
    if (options.content_hash_bits < 8 || options.content_hash_bits > 64)
        return "content_hash_bits must be in [8, 64]";
    if (options.zstd_level < ZSTD_minCLevel() || options.zstd_level > ZSTD_maxCLevel()) {
        return "zstd_level out of zstd's range";
    }
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
    impl->worker = std::thread([p = impl.get()] { p->worker_main(); });
    return std::unique_ptr<TraceWriter>(new TraceWriter(std::move(impl)));
}

TraceError TraceWriter::add_contents(const void* bytes, size_t size, uint64_t* hash) {
    const ContentPiece one{bytes, size};
    return add_contents(std::span<const ContentPiece>(&one, 1), hash);
}

TraceError TraceWriter::add_contents(std::span<const ContentPiece> pieces, uint64_t* hash) {
    Impl& w = *impl_;
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
    if (auto repeat = w.keys_by_fingerprint.find(known); repeat != w.keys_by_fingerprint.end()) {
        ++w.counters.contents_deduplicated;
        w.counters.contents_bytes_deduplicated += size;
        *hash = repeat->second;
        return {};
    }
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
        auto [it, inserted] = w.contents.try_emplace(key, StoredContents{size, fingerprint});
        if (!inserted) {
            if (it->second.size == size && XXH128_isEqual(it->second.fingerprint, fingerprint)) {
                ++w.counters.contents_deduplicated;
                w.counters.contents_bytes_deduplicated += size;
                *hash = key;
                return {};
            }
            if (seed == 0) ++w.counters.hash_collisions;
            if (seed > 1'000'000) {
                return make_trace_error(TraceErrorCode::kInvalidArgument, w.path, 0,
                                        "no free content key left");
            }
            continue;
        }
        w.fbb.Clear();
        uint8_t* vec_bytes = nullptr;
        auto vec = w.fbb.CreateUninitializedVector(size, &vec_bytes);
        for (const ContentPiece& p : pieces) {
            if (p.size) std::memcpy(vec_bytes, p.bytes, p.size);
            vec_bytes += p.size;
        }
        auto body = fbs::CreateMemoryContents(w.fbb, key, seed, vec);
        w.fbb.Finish(fbs::CreateRecord(w.fbb, fbs::RecordBody::MemoryContents, body.Union()));
        // The frame lands at the end of the current chunk, unless add_frame seals it first.
        size_t framed = format::kRecordFrameSize + format::align8(w.fbb.GetSize());
        bool seals = !w.raw.empty() && w.raw.size() + framed > w.options.chunk_raw_bytes;
        uint32_t chunk = w.next_chunk_number + (seals ? 1 : 0);
        uint32_t raw_offset = seals ? 0 : static_cast<uint32_t>(w.raw.size());
        if (TraceError e = w.add_frame(w.fbb.GetBufferPointer(), w.fbb.GetSize(),
                                       fbs::RecordBody::MemoryContents)) {
            w.contents.erase(it);
            return e;
        }
        w.keys_by_fingerprint.emplace(known, key);
        w.content_places.push_back({key, size, chunk, raw_offset});
        ++w.counters.contents_stored;
        w.counters.contents_bytes_stored += size;
        *hash = key;
        return {};
    }
}

TraceError TraceWriter::snapshot(uint64_t buffer, uint64_t offset, uint64_t address,
                                 const void* bytes, size_t size, fbs::MemorySnapshot* out) {
    uint64_t hash = 0;
    if (TraceError e = add_contents(bytes, size, &hash)) return e;
    *out = fbs::MemorySnapshot(buffer, offset, address, size, hash);
    return {};
}

TraceError TraceWriter::snapshot(uint64_t buffer, uint64_t offset, uint64_t address,
                                 std::span<const ContentPiece> pieces, fbs::MemorySnapshot* out) {
    uint64_t hash = 0;
    if (TraceError e = add_contents(pieces, &hash)) return e;
    uint64_t size = 0;
    for (const ContentPiece& p : pieces) size += p.size;
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
    w.queue_changed.wait(lock, [&] { return (w.queue.empty() && !w.worker_busy) || w.error; });
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
    s.compressor_placed = w.compressor_placed;
    return s;
}

}  // namespace clastrace::traces
