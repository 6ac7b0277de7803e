// SPDX-License-Identifier: Apache-2.0
// Chunks: reading and checking payloads, decompressing them within the budget, finding the next
// intact header, and taking the chunks in scan order.
#include "trace_reader_impl.h"

#include "chunk_streams.h"

#include <algorithm>
#include <cstring>
#include <string>
#include <utility>

namespace clastrace::traces {

using namespace reader;

bool TraceReader::Impl::take_from_budget(uint64_t n) const {
    uint64_t spent = raw_spent.load();
    do {
        if (spent > raw_budget || n > raw_budget - spent) return false;
    } while (!raw_spent.compare_exchange_weak(spent, spent + n));
    return true;
}

ChunkStatus TraceReader::Impl::read_chunk(uint64_t offset, format::ChunkHeader* h, ChunkBytes* out,
                                          TraceError* err) {
    ChunkStatus status = read_checked_payload(decoder, offset, h, err);
    return status == ChunkStatus::kOk ? decompress(offset, *h, out, err) : status;
}

ChunkStatus TraceReader::Impl::decompress(uint64_t offset, const format::ChunkHeader& h,
                                          ChunkBytes* out, TraceError* err) {
    ChunkStatus status = decompress_payload(decoder, offset, h, out, err);
    if (status == ChunkStatus::kOverBudget) budget_exhausted = true;
    return status;
}

void TraceReader::Impl::release_side_chunk_if_big() {
    release_if_big(side_raw);
    if (side_raw.capacity() == 0) side_offset = UINT64_MAX;
}

ChunkStatus TraceReader::Impl::read_checked_payload(ChunkDecoder& d, uint64_t offset,
                                                    format::ChunkHeader* h, TraceError* err) const {
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
        *err = error(TraceErrorCode::kLengthOutOfRange,
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
        // An intact index and trailer say the file ends where it should: the header lies, and
        // the chunks after it are still there to read.
        const bool file_whole = index != nullptr;
        *err = error(file_whole ? TraceErrorCode::kLengthOutOfRange : TraceErrorCode::kTruncated,
                     offset + offsetof(format::ChunkHeader, compressed_size),
                     what + " claims " + std::to_string(h->compressed_size) +
                         " compressed bytes but only " + std::to_string(size - payload) +
                         " remain in the file" +
                         (file_whole ? ", which its trailer says is whole" : ""));
        return file_whole ? ChunkStatus::kBadHeader : ChunkStatus::kTruncated;
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

ChunkStatus TraceReader::Impl::decompress_payload(ChunkDecoder& d, uint64_t offset,
                                                  const format::ChunkHeader& h, ChunkBytes* out,
                                                  TraceError* err) const {
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
                     what + " would inflate " + std::to_string(compressed.size()) + " bytes to " +
                         std::to_string(h.raw_size) + ", past the budget of " +
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
    size_t got =
        ZSTD_decompressDCtx(d.dctx, out->data(), out->size(), compressed.data(), compressed.size());
    if (ZSTD_isError(got) || got != h.raw_size) {
        *err =
            error(TraceErrorCode::kDecompressFailed, payload,
                  what + " does not decompress: " +
                      (ZSTD_isError(got) ? ZSTD_getErrorName(got) : std::string("size differs")));
        return ChunkStatus::kBadPayload;
    }
    return ChunkStatus::kOk;
}

uint64_t TraceReader::Impl::find_next_chunk(uint64_t from) {
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

void TraceReader::Impl::resync(uint64_t from) {
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

void TraceReader::Impl::report_budget_or(TraceError err) {
    if (err.code == TraceErrorCode::kLengthOutOfRange && budget_exhausted) {
        if (budget_reported) return;
        budget_reported = true;
    }
    report(std::move(err));
}

ChunkStatus TraceReader::Impl::take_chunk(format::ChunkHeader* h, TraceError* err, bool* have_raw) {
    *have_raw = false;
    std::optional<ReadAhead> taken;
    if (ahead.valid() && ahead_offset() == pos) taken = take_read_ahead();
    if (taken) {
        ReadAhead& r = *taken;
        *h = r.header;
        *err = std::move(r.error);
        if (r.status == ChunkStatus::kOverBudget) budget_exhausted = true;
        chunk_ahead = std::move(r.contents);
        frames_verified = std::move(r.verified);
        next_verified = 0;
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
    frames_verified.clear();
    return read_checked_payload(decoder, pos, h, err);
}

bool TraceReader::Impl::advance_chunk() {
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
            if (chunks_of_broken_frames.contains(here)) {
                follow_chunk(h);  // as its first reading left the order
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
            skip_unknown_kind(here, h);
            continue;
        }
        check_chunk_sequence(here, h);
        enter_chunk(here, h);
        return true;
    }
}

// Kinds added by a newer minor version are skipped; in a file this reader fully knows, an
// unknown kind is a records chunk whose label was changed.
void TraceReader::Impl::skip_unknown_kind(uint64_t here, const format::ChunkHeader& h) {
    if (version_minor > format::kVersionMinor) return;
    report(TraceErrorCode::kBadChunk, here,
           "chunk " + std::to_string(h.chunk_number) + " has kind " + std::to_string(h.kind) +
               ", which format " + std::to_string(version_major) + "." +
               std::to_string(version_minor) + " does not define; its " +
               std::to_string(h.record_count) + " records are skipped");
    ++stats.chunks_damaged;
}

// A records chunk's number and first submission against those its predecessor implies
// (unless a damaged chunk was skipped in between, whose count is unknown).
void TraceReader::Impl::check_chunk_sequence(uint64_t here, const format::ChunkHeader& h) {
    if (skipped_since_chunk) return;
    if (h.chunk_number != expected_chunk_number) {
        report(TraceErrorCode::kBadChunk, here,
               "chunk number " + std::to_string(h.chunk_number) + " where " +
                   std::to_string(expected_chunk_number) +
                   " was expected (chunks missing or reordered)");
    }
    if (h.first_submission != next_submission) {
        report(TraceErrorCode::kBadChunk, here,
               "chunk " + std::to_string(h.chunk_number) + " starts at submission " +
                   std::to_string(h.first_submission) + " but " + std::to_string(next_submission) +
                   " submissions precede it");
    }
}

// The decompressed records chunk at `here` becomes the one the cursor walks.
void TraceReader::Impl::enter_chunk(uint64_t here, const format::ChunkHeader& h) {
    follow_chunk(h);
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
}

void TraceReader::Impl::follow_chunk(const format::ChunkHeader& h) {
    next_submission = h.first_submission;
    expected_chunk_number = h.chunk_number + 1;
    have_last_chunk = true;
    last_chunk_number = h.chunk_number;
    skipped_since_chunk = false;
}

bool TraceReader::Impl::in_order(uint64_t at, const format::ChunkHeader& h) {
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

bool TraceReader::Impl::reached_index_chunk(uint64_t at, uint64_t after) {
    if (index) {
        if (at == index_offset) return true;
        report(TraceErrorCode::kBadIndex, at,
               "index chunk here but the trailer points at offset " + std::to_string(index_offset) +
                   "; the chunks after it are still read");
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

}  // namespace clastrace::traces
