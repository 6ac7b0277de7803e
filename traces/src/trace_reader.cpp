#include <clastrace/traces/trace_reader.h>

#include <clastrace/traces/records.h>

#include "byte_source.h"
#include "file_format.h"

#include <algorithm>
#include <cinttypes>
#include <cstdio>
#include <future>
#include <unordered_map>

#include <zstd.h>

namespace clastrace::traces {

namespace {

constexpr size_t kMaxDamageKept = 1000;
constexpr uint32_t kReadAheadMinRawBytes = 256u << 10;

std::string hex(uint64_t v) {
    char buf[24];
    std::snprintf(buf, sizeof buf, "0x%016" PRIx64, v);
    return buf;
}

// Where the bytes of one content live: which chunk, and where its frame starts in it.
struct ContentPlace {
    uint64_t size;
    uint64_t chunk_offset;
    uint32_t raw_offset;
    bool seen_in_scan;  // defined by a record the scan already passed
};

enum class ChunkStatus {
    ok,
    bad_header,   // header unusable: look for the next chunk header byte by byte
    bad_payload,  // header fine, payload not: skip exactly this chunk
    truncated,    // the file ends inside this chunk
};

enum class RecordStatus { ok, skip, stop_chunk };

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
    ChunkStatus status = ChunkStatus::ok;
    TraceError error;
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
    bool chunk_cut_short = false;
    uint64_t next_submission = 0;
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

    // Reads, checks and decompresses the chunk whose header is at `offset`.
    ChunkStatus read_chunk(uint64_t offset, format::ChunkHeader* h, std::vector<uint8_t>* out, TraceError* err) {
        return read_chunk_with(decoder, offset, h, out, err);
    }

    // Safe to run on the read-ahead task: touches only `d`, `out` and the (thread-safe) source.
    ChunkStatus read_chunk_with(ChunkDecoder& d, uint64_t offset, format::ChunkHeader* h, std::vector<uint8_t>* out,
                                TraceError* err) const {
        std::vector<uint8_t>& compressed = d.compressed;
        if (offset > size || size - offset < format::kChunkHeaderSize) {
            *err = error(TraceErrorCode::truncated, offset,
                         "file ends inside a chunk header (" + std::to_string(size - std::min(size, offset)) +
                             " of " + std::to_string(format::kChunkHeaderSize) + " bytes present)");
            return ChunkStatus::truncated;
        }
        uint8_t bytes[format::kChunkHeaderSize];
        if (!src->read_at(offset, sizeof bytes, bytes)) {
            *err = error(TraceErrorCode::io_error, offset, "read failed: " + src->last_error());
            return ChunkStatus::truncated;
        }
        std::memcpy(h, bytes, sizeof *h);
        if (h->magic != format::kChunkMagic) {
            *err = error(TraceErrorCode::bad_chunk, offset, "no chunk header here (magic " + hex(h->magic) + ")");
            return ChunkStatus::bad_header;
        }
        uint64_t computed = format::chunk_header_checksum(*h);
        if (computed != h->header_checksum) {
            *err = error(TraceErrorCode::checksum_mismatch, offset,
                         "chunk header checksum mismatch (stored " + hex(h->header_checksum) + ", computed " +
                             hex(computed) + ")");
            return ChunkStatus::bad_header;
        }
        const std::string what = "chunk " + std::to_string(h->chunk_number);
        uint32_t max_raw = h->kind == static_cast<uint16_t>(format::ChunkKind::index) ? format::kMaxIndexRawBytes
                                                                                       : format::kMaxChunkRawBytes;
        if (h->raw_size > max_raw) {
            *err = error(TraceErrorCode::length_out_of_range, offset + offsetof(format::ChunkHeader, raw_size),
                         what + " claims " + std::to_string(h->raw_size) + " raw bytes, over the limit of " +
                             std::to_string(max_raw));
            return ChunkStatus::bad_header;
        }
        if (h->compressed_size > ZSTD_compressBound(h->raw_size)) {
            *err = error(TraceErrorCode::length_out_of_range, offset + offsetof(format::ChunkHeader, compressed_size),
                         what + " claims " + std::to_string(h->compressed_size) +
                             " compressed bytes, more than zstd can produce from " + std::to_string(h->raw_size));
            return ChunkStatus::bad_header;
        }
        uint64_t payload = offset + format::kChunkHeaderSize;
        if (h->compressed_size > size - payload) {
            *err = error(TraceErrorCode::truncated, offset + offsetof(format::ChunkHeader, compressed_size),
                         what + " claims " + std::to_string(h->compressed_size) + " compressed bytes but only " +
                             std::to_string(size - payload) + " remain in the file");
            return ChunkStatus::truncated;
        }
        compressed.resize(h->compressed_size);
        if (!src->read_at(payload, compressed.size(), compressed.data())) {
            *err = error(TraceErrorCode::io_error, payload, "read failed: " + src->last_error());
            return ChunkStatus::truncated;
        }
        computed = format::checksum(compressed.data(), compressed.size());
        if (computed != h->payload_checksum) {
            *err = error(TraceErrorCode::checksum_mismatch, payload,
                         what + " checksum mismatch (stored " + hex(h->payload_checksum) + ", computed " +
                             hex(computed) + ")");
            return ChunkStatus::bad_payload;
        }
        unsigned long long content = ZSTD_getFrameContentSize(compressed.data(), compressed.size());
        if (content != h->raw_size) {
            *err = error(TraceErrorCode::decompress_failed, payload,
                         what + " zstd frame does not declare the chunk's " + std::to_string(h->raw_size) + " raw bytes");
            return ChunkStatus::bad_payload;
        }
        out->resize(h->raw_size);
        size_t got = ZSTD_decompressDCtx(d.dctx, out->data(), out->size(), compressed.data(), compressed.size());
        if (ZSTD_isError(got) || got != h->raw_size) {
            *err = error(TraceErrorCode::decompress_failed, payload,
                         what + " does not decompress: " +
                             (ZSTD_isError(got) ? ZSTD_getErrorName(got) : std::string("size differs")));
            return ChunkStatus::bad_payload;
        }
        return ChunkStatus::ok;
    }

    // Finds the next offset >= from holding a chunk header whose checksum holds.
    uint64_t find_next_chunk(uint64_t from) {
        constexpr size_t kBlock = 1 << 20;
        std::vector<uint8_t> block;
        const uint8_t magic[4] = {'C', 'L', 'C', 'K'};
        uint64_t at = from;
        while (at + format::kChunkHeaderSize <= size) {
            size_t n = static_cast<size_t>(std::min<uint64_t>(kBlock + format::kChunkHeaderSize, size - at));
            block.resize(n);
            if (!src->read_at(at, n, block.data())) return size;
            for (size_t i = 0; i + format::kChunkHeaderSize <= n; ++i) {
                if (block[i] != magic[0] || std::memcmp(&block[i], magic, 4) != 0) continue;
                format::ChunkHeader h;
                std::memcpy(&h, &block[i], sizeof h);
                if (format::chunk_header_checksum(h) == h.header_checksum) return at + i;
            }
            if (n < kBlock + format::kChunkHeaderSize) break;
            at += kBlock;
        }
        return size;
    }

    void resync(uint64_t from) {
        uint64_t found = find_next_chunk(from);
        if (found > from) {
            stats.bytes_skipped += found - from;
            report(TraceErrorCode::bad_chunk, from,
                   "skipped " + std::to_string(found - from) + " bytes up to offset " + std::to_string(found) +
                       (found < size ? " to reach the next intact chunk header" : " (no further chunk header found)"));
        }
        pos = found;
        skipped_since_chunk = true;
    }

    std::string record_place(uint32_t raw_offset) const {
        return "chunk " + std::to_string(chunk.chunk_number) + " record " + std::to_string(chunk_records_seen) +
               " (raw offset " + std::to_string(raw_offset) + ")";
    }

    // Decodes the record at `cursor` of the loaded chunk.
    RecordStatus parse_record(RecordView* out) {
        const uint32_t at = static_cast<uint32_t>(cursor);
        const size_t remaining = raw.size() - cursor;
        if (remaining < format::kRecordFrameSize) {
            report(TraceErrorCode::invalid_record, chunk_offset,
                   record_place(at) + ": frame needs 8 bytes, " + std::to_string(remaining) + " remain");
            return RecordStatus::stop_chunk;
        }
        uint32_t rsize = format::load<uint32_t>(raw.data() + cursor);
        uint32_t rkind = format::load<uint32_t>(raw.data() + cursor + 4);
        if (rsize > remaining - format::kRecordFrameSize) {
            report(TraceErrorCode::length_out_of_range, chunk_offset,
                   record_place(at) + ": claims " + std::to_string(rsize) + " bytes, only " +
                       std::to_string(remaining - format::kRecordFrameSize) + " remain in the chunk");
            return RecordStatus::stop_chunk;
        }
        const uint8_t* bytes = raw.data() + cursor + format::kRecordFrameSize;
        cursor = std::min<size_t>(raw.size(), cursor + format::kRecordFrameSize + format::align8(rsize));
        ++chunk_records_seen;

        flatbuffers::Verifier verifier(bytes, rsize, 64, 10'000'000);
        if (!fbs::VerifyRecordBuffer(verifier)) {
            report(TraceErrorCode::invalid_record, chunk_offset, record_place(at) + ": fails the FlatBuffers verifier");
            return RecordStatus::skip;
        }
        const fbs::Record* record = fbs::GetRecord(bytes);
        fbs::RecordBody kind = record->body_type();
        if (static_cast<uint32_t>(kind) != rkind) {
            report(TraceErrorCode::invalid_record, chunk_offset,
                   record_place(at) + ": frame says kind " + std::to_string(rkind) + ", record holds " +
                       std::to_string(static_cast<unsigned>(kind)));
            return RecordStatus::skip;
        }
        if (kind == fbs::RecordBody::NONE || record->body() == nullptr) {
            report(TraceErrorCode::invalid_record, chunk_offset, record_place(at) + ": record has no body");
            return RecordStatus::skip;
        }
        if (!check_record(*record, at)) return RecordStatus::skip;

        out->record = record;
        out->kind = kind;
        out->bytes = bytes;
        out->size = rsize;
        out->chunk_offset = chunk_offset;
        out->chunk_number = chunk.chunk_number;
        out->raw_offset = at;
        return RecordStatus::ok;
    }

    // Rules beyond the verifier: content keys, snapshot references, submission order.
    bool check_record(const fbs::Record& record, uint32_t at) {
        if (const auto* c = record.body_as_MemoryContents()) {
            const uint8_t* data = c->bytes() ? c->bytes()->data() : nullptr;
            size_t n = c->bytes() ? c->bytes()->size() : 0;
            uint64_t key = options.verify_content_keys ? format::content_key(data, n, c->seed(), hash_bits) : c->hash();
            if (key != c->hash()) {
                report(TraceErrorCode::content_mismatch, chunk_offset,
                       record_place(at) + ": contents " + hex(c->hash()) + " hold bytes hashing to " + hex(key));
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
                    report(TraceErrorCode::missing_contents, chunk_offset,
                           record_place(at) + " (" + record_kind_name(record.body_type()) + "): snapshot of address " +
                               hex(s->address()) + " refers to contents " + hex(s->hash()) +
                               " that no earlier record defines");
                    ok = false;
                } else if (it->second.size != s->size()) {
                    report(TraceErrorCode::content_mismatch, chunk_offset,
                           record_place(at) + ": snapshot size " + std::to_string(s->size()) + " but contents " +
                               hex(s->hash()) + " hold " + std::to_string(it->second.size) + " bytes");
                    ok = false;
                }
            }
        }
        if (!ok) return false;
        if (const auto* q = record.body_as_QueueSubmit()) {
            if (q->submission_index() != next_submission) {
                report(TraceErrorCode::invalid_record, chunk_offset,
                       record_place(at) + ": submission_index " + std::to_string(q->submission_index()) +
                           ", expected " + std::to_string(next_submission));
            }
            next_submission = q->submission_index() + 1;
        }
        return true;
    }

    void close_chunk() {
        if (chunk_loaded && !chunk_cut_short && chunk_records_seen != chunk.record_count) {
            report(TraceErrorCode::invalid_record, chunk_offset,
                   "chunk " + std::to_string(chunk.chunk_number) + " header says " + std::to_string(chunk.record_count) +
                       " records, its payload holds " + std::to_string(chunk_records_seen));
        }
        chunk_loaded = false;
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
            r.status = read_chunk_with(ahead_decoder, offset, &r.header, &ahead_raw, &r.error);
            return r;
        });
    }

    void drop_read_ahead() {
        if (ahead.valid()) ahead.wait();
        ahead = {};
        ahead_started_at = UINT64_MAX;
    }

    // Loads the next intact record chunk; false at the end of the records.
    bool advance_chunk() {
        for (;;) {
            if (pos >= size) return false;
            TraceError err;
            format::ChunkHeader h{};
            ChunkStatus status;
            if (ahead.valid() && ahead_offset() == pos) {
                ReadAhead r = ahead.get();
                std::swap(raw, ahead_raw);
                h = r.header;
                status = r.status;
                err = std::move(r.error);
            } else {
                drop_read_ahead();
                status = read_chunk(pos, &h, &raw, &err);
            }
            // Reading ahead pays for big chunks; for small ones a task costs more than it hides.
            if (status == ChunkStatus::ok && h.raw_size >= kReadAheadMinRawBytes) {
                start_read_ahead(pos + format::kChunkHeaderSize + h.compressed_size);
            }
            switch (status) {
            case ChunkStatus::truncated:
                report(std::move(err));
                ++stats.chunks_damaged;
                pos = size;
                return false;
            case ChunkStatus::bad_header:
                report(std::move(err));
                resync(pos + 1);
                continue;
            case ChunkStatus::bad_payload:
                report(std::move(err));
                ++stats.chunks_damaged;
                pos += format::kChunkHeaderSize + h.compressed_size;
                skipped_since_chunk = true;
                continue;
            case ChunkStatus::ok: break;
            }
            uint64_t here = pos;
            pos += format::kChunkHeaderSize + h.compressed_size;
            if (h.kind == static_cast<uint16_t>(format::ChunkKind::index)) {
                reached_index_chunk(here, pos);
                return false;
            }
            if (h.kind != static_cast<uint16_t>(format::ChunkKind::records)) continue;  // newer kind: skip
            if (!skipped_since_chunk && h.chunk_number != expected_chunk_number) {
                report(TraceErrorCode::bad_chunk, here,
                       "chunk number " + std::to_string(h.chunk_number) + " where " +
                           std::to_string(expected_chunk_number) + " was expected (chunks missing or reordered)");
            }
            if (!skipped_since_chunk && h.first_submission != next_submission) {
                report(TraceErrorCode::bad_chunk, here,
                       "chunk " + std::to_string(h.chunk_number) + " starts at submission " +
                           std::to_string(h.first_submission) + " but " + std::to_string(next_submission) +
                           " submissions precede it");
            }
            next_submission = h.first_submission;
            expected_chunk_number = h.chunk_number + 1;
            skipped_since_chunk = false;
            chunk = h;
            chunk_offset = here;
            chunk_loaded = true;
            chunk_cut_short = false;
            cursor = 0;
            chunk_records_seen = 0;
            ++stats.chunks_read;
            stats.raw_bytes += h.raw_size;
            stats.compressed_bytes += h.compressed_size;
            return true;
        }
    }

    void reached_index_chunk(uint64_t at, uint64_t after) {
        if (index) {
            if (at != index_offset) {
                report(TraceErrorCode::bad_index, at,
                       "index chunk here but the trailer points at offset " + std::to_string(index_offset));
            }
            return;
        }
        // No usable trailer at the end of the file: is there one right after this index?
        if (size - after >= format::kTrailerSize) {
            format::Trailer t{};
            if (src->read_at(after, sizeof t, reinterpret_cast<uint8_t*>(&t)) &&
                std::memcmp(t.magic, format::kTrailerMagic, 8) == 0 && format::trailer_checksum(t) == t.checksum &&
                after + format::kTrailerSize < size) {
                report(TraceErrorCode::trailing_bytes, after + format::kTrailerSize,
                       std::to_string(size - after - format::kTrailerSize) + " bytes after the trailer");
            }
        }
    }

    bool next(RecordView* out) {
        if (has_pending) {
            *out = pending;
            has_pending = false;
            ++stats.records;
            return true;
        }
        for (;;) {
            if (chunk_loaded && cursor < raw.size()) {
                RecordStatus s = parse_record(out);
                if (s == RecordStatus::ok) {
                    ++stats.records;
                    return true;
                }
                ++stats.records_damaged;
                if (s == RecordStatus::stop_chunk) {
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
        has_pending = false;
        ended = false;
        pos = offset;
        skipped_since_chunk = true;
    }

    TraceError seek(uint64_t k) {
        seeked = true;
        if (index) {
            if (k >= index->submission_count()) {
                return error(TraceErrorCode::invalid_argument, 0,
                             "submission " + std::to_string(k) + " requested, the trace has " +
                                 std::to_string(index->submission_count()));
            }
            const auto* chunks = index->chunks();
            const fbs::ChunkLocation* found = nullptr;
            for (const fbs::ChunkLocation* c : *chunks) {
                if (c->submission_count() > 0 && c->first_submission() <= k && k - c->first_submission() < c->submission_count()) {
                    found = c;
                    break;
                }
            }
            if (!found || found->file_offset() < data_start || found->file_offset() >= size) {
                return error(TraceErrorCode::bad_index, index_offset,
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
        return error(TraceErrorCode::invalid_argument, 0,
                     "submission " + std::to_string(k) + " not found" + (index ? "" : " (trace has no index)"));
    }

    TraceError read_contents(uint64_t hash, std::vector<uint8_t>* out) {
        auto it = contents.find(hash);
        if (it == contents.end()) {
            return error(TraceErrorCode::missing_contents, 0, "no contents with hash " + hex(hash) + " in the trace");
        }
        const ContentPlace place = it->second;
        const std::vector<uint8_t>* source = nullptr;
        if (chunk_loaded && place.chunk_offset == chunk_offset) {
            source = &raw;
        } else {
            if (side_offset != place.chunk_offset) {
                format::ChunkHeader h{};
                TraceError err;
                side_offset = UINT64_MAX;
                if (read_chunk(place.chunk_offset, &h, &side_raw, &err) != ChunkStatus::ok) return err;
                side_offset = place.chunk_offset;
            }
            source = &side_raw;
        }
        const std::vector<uint8_t>& r = *source;
        auto bad = [&](const std::string& why) {
            return error(TraceErrorCode::bad_index, place.chunk_offset,
                         "contents " + hex(hash) + " not found at raw offset " + std::to_string(place.raw_offset) + ": " + why);
        };
        if (place.raw_offset > r.size() || r.size() - place.raw_offset < format::kRecordFrameSize) return bad("outside the chunk");
        uint32_t rsize = format::load<uint32_t>(r.data() + place.raw_offset);
        if (rsize > r.size() - place.raw_offset - format::kRecordFrameSize) return bad("frame overruns the chunk");
        const uint8_t* bytes = r.data() + place.raw_offset + format::kRecordFrameSize;
        flatbuffers::Verifier verifier(bytes, rsize, 64, 10'000'000);
        if (!fbs::VerifyRecordBuffer(verifier)) return bad("record fails the verifier");
        const auto* c = fbs::GetRecord(bytes)->body_as_MemoryContents();
        if (!c || c->hash() != hash) return bad("another record is there");
        const uint8_t* data = c->bytes() ? c->bytes()->data() : nullptr;
        size_t n = c->bytes() ? c->bytes()->size() : 0;
        if (format::content_key(data, n, c->seed(), hash_bits) != hash) {
            return error(TraceErrorCode::content_mismatch, place.chunk_offset,
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
        if (size == 0) return error(TraceErrorCode::truncated, 0, "empty file");
        if (size < format::kFileHeaderSize) {
            if (size >= 8 && std::memcmp(read_small(0, 8).data(), format::kFileMagic, 8) != 0) {
                return error(TraceErrorCode::not_a_trace, 0, "not a clastrace trace (wrong magic)");
            }
            return error(TraceErrorCode::truncated, size,
                         "file of " + std::to_string(size) + " bytes is shorter than the 32-byte file header");
        }
        format::FileHeader fh{};
        if (!src->read_at(0, sizeof fh, reinterpret_cast<uint8_t*>(&fh))) {
            return error(TraceErrorCode::io_error, 0, "read failed: " + src->last_error());
        }
        if (std::memcmp(fh.magic, format::kFileMagic, 8) != 0) {
            return error(TraceErrorCode::not_a_trace, 0, "not a clastrace trace (wrong magic)");
        }
        version_major = fh.version_major;
        version_minor = fh.version_minor;
        if (fh.version_major != format::kVersionMajor) {
            return error(TraceErrorCode::unsupported_version, offsetof(format::FileHeader, version_major),
                         "format version " + std::to_string(fh.version_major) + "." + std::to_string(fh.version_minor) +
                             " is not supported (this reader reads " + std::to_string(format::kVersionMajor) + ".x)");
        }
        if (fh.trace_header_size > format::kMaxTraceHeaderBytes ||
            fh.trace_header_size > size - format::kFileHeaderSize) {
            report(TraceErrorCode::length_out_of_range, offsetof(format::FileHeader, trace_header_size),
                   "trace header claims " + std::to_string(fh.trace_header_size) + " bytes (limit " +
                       std::to_string(format::kMaxTraceHeaderBytes) + ", file has " +
                       std::to_string(size - format::kFileHeaderSize) + " after the file header)");
            data_start = format::kFileHeaderSize;
            restart_at(data_start);
            resync(data_start);
        } else {
            header_bytes.resize(fh.trace_header_size);
            if (!src->read_at(format::kFileHeaderSize, header_bytes.size(), header_bytes.data())) {
                return error(TraceErrorCode::io_error, format::kFileHeaderSize, "read failed: " + src->last_error());
            }
            data_start = format::kFileHeaderSize + format::align8(fh.trace_header_size);
            // The padding to 8 bytes is outside every checksum, so it must be zero.
            uint64_t pad_at = format::kFileHeaderSize + fh.trace_header_size;
            if (data_start <= size) {
                std::vector<uint8_t> pad = read_small(pad_at, static_cast<size_t>(data_start - pad_at));
                if (std::any_of(pad.begin(), pad.end(), [](uint8_t b) { return b != 0; })) {
                    report(TraceErrorCode::bad_chunk, pad_at, "non-zero padding after the trace header");
                }
            }
            uint64_t computed = format::file_header_checksum(fh, header_bytes.data(), header_bytes.size());
            if (computed != fh.checksum) {
                report(TraceErrorCode::checksum_mismatch, offsetof(format::FileHeader, checksum),
                       "file header checksum mismatch (stored " + hex(fh.checksum) + ", computed " + hex(computed) + ")");
            } else {
                flatbuffers::Verifier verifier(header_bytes.data(), header_bytes.size(), 64, 1'000'000);
                if (!verifier.VerifyBuffer<fbs::TraceHeader>(nullptr)) {
                    report(TraceErrorCode::invalid_record, format::kFileHeaderSize,
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
            report(TraceErrorCode::truncated, size, "no trailer: the file was cut or its writer never finished");
            return;
        }
        const uint64_t trailer_at = size - format::kTrailerSize;
        format::Trailer t{};
        if (!src->read_at(trailer_at, sizeof t, reinterpret_cast<uint8_t*>(&t))) return;
        if (std::memcmp(t.magic, format::kTrailerMagic, 8) != 0) {
            report(TraceErrorCode::truncated, size,
                   "no trailer at the end of the file: it was cut or its writer never finished");
            return;
        }
        uint64_t computed = format::trailer_checksum(t);
        if (computed != t.checksum) {
            report(TraceErrorCode::bad_index, trailer_at,
                   "trailer checksum mismatch (stored " + hex(t.checksum) + ", computed " + hex(computed) + ")");
            return;
        }
        if (t.trailer_offset != trailer_at || t.index_offset < data_start ||
            t.index_offset > trailer_at - std::min<uint64_t>(trailer_at, format::kChunkHeaderSize)) {
            report(TraceErrorCode::bad_index, trailer_at, "trailer points outside the file");
            return;
        }
        format::ChunkHeader h{};
        TraceError err;
        if (read_chunk(t.index_offset, &h, &index_raw, &err) != ChunkStatus::ok) {
            err.code = err.code == TraceErrorCode::truncated ? TraceErrorCode::bad_index : err.code;
            err.message += " (index chunk)";
            report(std::move(err));
            return;
        }
        if (h.kind != static_cast<uint16_t>(format::ChunkKind::index) ||
            t.index_offset + format::kChunkHeaderSize + h.compressed_size != trailer_at) {
            report(TraceErrorCode::bad_index, t.index_offset, "trailer does not point at the index chunk");
            return;
        }
        flatbuffers::Verifier verifier(index_raw.data(), index_raw.size(), 64, 10'000'000);
        if (!verifier.VerifyBuffer<fbs::TraceIndex>(nullptr)) {
            report(TraceErrorCode::bad_index, t.index_offset, "index fails the FlatBuffers verifier");
            return;
        }
        const auto* idx = flatbuffers::GetRoot<fbs::TraceIndex>(index_raw.data());
        if (!idx->chunks()) {
            report(TraceErrorCode::bad_index, t.index_offset, "index lists no chunks");
            return;
        }
        // The index chunk's own header must agree with what it indexes.
        if (h.record_count != 0 || h.first_submission != idx->submission_count() ||
            h.chunk_number != idx->chunks()->size()) {
            report(TraceErrorCode::bad_index, t.index_offset,
                   "index chunk header disagrees with the index (record count " + std::to_string(h.record_count) +
                       ", first submission " + std::to_string(h.first_submission) + ", chunk number " +
                       std::to_string(h.chunk_number) + ")");
            return;
        }
        index = idx;
        index_offset = t.index_offset;
        if (const auto* places = index->contents()) {
            const auto* chunks = index->chunks();
            contents.reserve(places->size());
            for (const fbs::ContentLocation* c : *places) {
                if (c->chunk() >= chunks->size()) continue;
                contents.emplace(c->hash(), ContentPlace{c->size(), chunks->Get(c->chunk())->file_offset(),
                                                         c->raw_offset(), false});
            }
        }
    }
};

TraceReader::TraceReader(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
TraceReader::~TraceReader() = default;

static std::unique_ptr<TraceReader::Impl> make_impl(std::unique_ptr<ByteSource> src, const std::string& name,
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
        *error = make_trace_error(TraceErrorCode::io_error, path, 0, "cannot open: " + why);
        return nullptr;
    }
    auto impl = make_impl(std::move(src), path, options);
    if (TraceError e = impl->open()) {
        *error = std::move(e);
        return nullptr;
    }
    return std::unique_ptr<TraceReader>(new TraceReader(std::move(impl)));
}

std::unique_ptr<TraceReader> TraceReader::open_memory(const uint8_t* data, size_t size, const std::string& name,
                                                      TraceError* error, const TraceReaderOptions& options) {
    auto impl = make_impl(memory_source(data, size), name, options);
    if (TraceError e = impl->open()) {
        *error = std::move(e);
        return nullptr;
    }
    return std::unique_ptr<TraceReader>(new TraceReader(std::move(impl)));
}

uint16_t TraceReader::version_major() const { return impl_->version_major; }
uint16_t TraceReader::version_minor() const { return impl_->version_minor; }
const fbs::TraceHeader* TraceReader::header() const { return impl_->header; }
bool TraceReader::has_index() const { return impl_->index != nullptr; }
uint64_t TraceReader::indexed_submission_count() const {
    return impl_->index ? impl_->index->submission_count() : 0;
}
bool TraceReader::next(RecordView* out) { return impl_->next(out); }
TraceError TraceReader::seek_to_submission(uint64_t k) { return impl_->seek(k); }
TraceError TraceReader::read_contents(uint64_t hash, std::vector<uint8_t>* out) { return impl_->read_contents(hash, out); }
const std::vector<TraceError>& TraceReader::damage() const { return impl_->damage; }
uint64_t TraceReader::damage_count() const { return impl_->damage_total; }
const TraceReadStats& TraceReader::stats() const { return impl_->stats; }

}  // namespace clastrace::traces
