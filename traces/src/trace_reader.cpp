// SPDX-License-Identifier: Apache-2.0
#include <clastrace/traces/trace_reader.h>

#include <clastrace/common/debug_assert.h>
#include <clastrace/common/hex.h>

#include <clastrace/traces/records.h>

#include "byte_source.h"
#include "file_format.h"

#include <algorithm>
#include <atomic>
#include <cinttypes>
#include <cstdio>
#include <future>
#include <unordered_map>

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

// Frees a buffer whose capacity a big chunk left behind, so it does not linger.
void release_if_big(std::vector<uint8_t>& buffer, size_t needed = 0) {
    if (buffer.capacity() > kBigBufferBytes && buffer.capacity() > 2 * needed)
        std::vector<uint8_t>().swap(buffer);
}

// What one thread needs to read a chunk: the reader uses one set on its own thread
// and one on the read-ahead task, so decompressing chunk n+1 overlaps the checks of chunk n.
struct ChunkDecoder {
    std::vector<uint8_t> compressed;
    ZSTD_DCtx* dctx = ZSTD_createDCtx();
    ChunkDecoder() = default;
    ChunkDecoder(const ChunkDecoder&) = delete;
    ChunkDecoder& operator=(const ChunkDecoder&) = delete;
    ~ChunkDecoder() { ZSTD_freeDCtx(dctx); }
};

// A chunk read ahead of need, at the offset the reader will ask for next.
struct ReadAhead {
    uint64_t offset = 0;
    format::ChunkHeader header{};
    ChunkStatus status = ChunkStatus::kOk;
    TraceError error;
    bool decompressed = false;  // false for chunks left to the reader's thread (big or not records)
};

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
    std::vector<uint8_t> index_raw;
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
    std::vector<uint8_t> raw;
    // Read-ahead: a task decompressing the next chunk into ahead_raw with its own decoder.
    ChunkDecoder ahead_decoder;
    std::vector<uint8_t> ahead_raw;
    std::future<ReadAhead> ahead;
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
    std::vector<uint8_t> side_raw;
    uint64_t side_offset = UINT64_MAX;

    std::vector<TraceError> damage;
    uint64_t damage_total = 0;
    TraceReadStats stats;

    ~Impl() { drop_read_ahead(); }

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
    ChunkStatus read_chunk(uint64_t offset, format::ChunkHeader* h, std::vector<uint8_t>* out,
                           TraceError* err) {
        ChunkStatus status = read_checked_payload(decoder, offset, h, err);
        return status == ChunkStatus::kOk ? decompress(offset, *h, out, err) : status;
    }

    // decompress_payload on the reader's own thread and decoder, noting a spent budget.
    ChunkStatus decompress(uint64_t offset, const format::ChunkHeader& h, std::vector<uint8_t>* out,
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
        std::vector<uint8_t>& compressed = d.compressed;
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
        compressed.resize(h->compressed_size);
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
                                   std::vector<uint8_t>* out, TraceError* err) const {
        const std::vector<uint8_t>& compressed = d.compressed;
        const uint64_t payload = offset + format::kChunkHeaderSize;
        const std::string what = "chunk " + std::to_string(h.chunk_number);
        unsigned long long content = ZSTD_getFrameContentSize(compressed.data(), compressed.size());
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
        out->resize(h.raw_size);
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
        if (const auto* c = record.body_as_MemoryContents()) {
            const uint8_t* data = c->bytes() ? c->bytes()->data() : nullptr;
            size_t n = c->bytes() ? c->bytes()->size() : 0;
            uint64_t key = options.verify_content_keys
                               ? format::content_key(data, n, c->seed(), hash_bits)
                               : c->hash();
            if (key != c->hash()) {
                report_with(TraceErrorCode::kContentMismatch, chunk_offset, [&] {
                    return record_place(at) + ": contents " + hex(c->hash()) +
                           " hold bytes hashing to " + hex(key);
                });
                return false;
            }
            contents[c->hash()] = ContentPlace{n, chunk_offset, at, true};
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

    void close_chunk() {
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

    void start_read_ahead(uint64_t offset) {
        drop_read_ahead();
        if (offset >= size || size - offset < format::kChunkHeaderSize) return;
        ahead_started_at = offset;
        ahead = std::async(std::launch::async, [this, offset] {
            ReadAhead r;
            r.offset = offset;
            r.status = read_checked_payload(ahead_decoder, offset, &r.header, &r.error);
            if (r.status == ChunkStatus::kOk &&
                r.header.kind == static_cast<uint16_t>(format::ChunkKind::kRecords) &&
                r.header.raw_size <= kReadAheadMaxRawBytes) {
                r.status =
                    decompress_payload(ahead_decoder, offset, r.header, &ahead_raw, &r.error);
                r.decompressed = r.status == ChunkStatus::kOk;
            }
            return r;
        });
    }

    void drop_read_ahead() {
        if (ahead.valid()) ahead.wait();
        ahead = {};
        ahead_started_at = UINT64_MAX;
    }

    // The chunk at `pos`: from the read-ahead when it read this offset, else read here.
    // With *have_raw false and status ok only the checked compressed payload is in `decoder`.
    ChunkStatus take_chunk(format::ChunkHeader* h, TraceError* err, bool* have_raw) {
        *have_raw = false;
        if (ahead.valid() && ahead_offset() == pos) {
            ReadAhead r = ahead.get();
            ahead_started_at = UINT64_MAX;
            *h = r.header;
            *err = std::move(r.error);
            if (r.status == ChunkStatus::kOverBudget) budget_exhausted = true;
            if (r.decompressed) {
                std::swap(raw, ahead_raw);
                release_if_big(ahead_raw);
                *have_raw = true;
            } else if (r.status == ChunkStatus::kOk) {
                std::swap(decoder.compressed, ahead_decoder.compressed);
            }
            return r.status;
        }
        drop_read_ahead();
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
                    status = decompress(here, h, &raw, &err);
                }
            }
            // Reading ahead pays for big chunks; for small ones a task costs more than it hides.
            if (status == ChunkStatus::kOk && is_records && h.raw_size >= kReadAheadMinRawBytes) {
                start_read_ahead(pos + format::kChunkHeaderSize + h.compressed_size);
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

    TraceError read_contents(uint64_t hash, std::vector<uint8_t>* out) {
        auto it = contents.find(hash);
        if (it == contents.end()) {
            return error(TraceErrorCode::kMissingContents, 0,
                         "no contents with hash " + hex(hash) + " in the trace");
        }
        const ContentPlace place = it->second;
        const std::vector<uint8_t>* source = nullptr;
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
                    if (h.raw_size > kBigBufferBytes && raw.capacity() > kBigBufferBytes &&
                        chunk_loaded) {
                        std::vector<uint8_t>().swap(raw);
                        raw_evicted = true;
                    }
                    status = decompress(place.chunk_offset, h, &side_raw, &err);
                }
                if (status == ChunkStatus::kOverBudget) report_budget_or(err);
                if (status != ChunkStatus::kOk) return err;
                side_offset = place.chunk_offset;
            }
            source = &side_raw;
        }
        const std::vector<uint8_t>& r = *source;
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
        const auto* c = fbs::GetRecord(bytes)->body_as_MemoryContents();
        if (!c || c->hash() != hash) return bad("another record is there");
        const uint8_t* data = c->bytes() ? c->bytes()->data() : nullptr;
        size_t n = c->bytes() ? c->bytes()->size() : 0;
        if (format::content_key(data, n, c->seed(), hash_bits) != hash) {
            return error(TraceErrorCode::kContentMismatch, place.chunk_offset,
                         "contents " + hex(hash) + " hold bytes that hash differently");
        }
        out->assign(data, data + n);
        return {};
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
    return impl_->stats;
}

}  // namespace clastrace::traces
