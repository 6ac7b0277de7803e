// SPDX-License-Identifier: Apache-2.0
// The read-ahead task: the next chunk read, checked and decompressed off the reader's thread, and
// the real bytes of its contents made from the bases the task keeps.
#include "trace_reader_impl.h"

#include <algorithm>
#include <cstring>

namespace clastrace::traces::reader {

std::optional<ContentsRecord> contents_in_frame(const ChunkBytes& raw, uint32_t at) {
    if (at > raw.size() || raw.size() - at < format::kRecordFrameSize) return std::nullopt;
    const uint32_t rsize = format::load<uint32_t>(raw.data() + at);
    if (rsize > raw.size() - at - format::kRecordFrameSize) return std::nullopt;
    const uint8_t* bytes = raw.data() + at + format::kRecordFrameSize;
    flatbuffers::Verifier verifier(bytes, rsize, 64, 10'000'000);
    if (!fbs::VerifyRecordBuffer(verifier)) return std::nullopt;
    return contents_record(*fbs::GetRecord(bytes));
}

std::vector<uint32_t> verified_frames(const ChunkBytes& raw) {
    std::vector<uint32_t> verified;
    uint32_t failed = 0;
    size_t next_frame = 0;
    while (raw.size() - next_frame >= format::kRecordFrameSize) {
        const auto at = static_cast<uint32_t>(next_frame);
        const uint32_t rsize = format::load<uint32_t>(raw.data() + at);
        if (rsize > raw.size() - at - format::kRecordFrameSize) break;
        next_frame = std::min<size_t>(raw.size(), next_frame + format::kRecordFrameSize +
                                                      format::align8(rsize));
        flatbuffers::Verifier verifier(raw.data() + at + format::kRecordFrameSize, rsize, 64,
                                       10'000'000);
        if (fbs::VerifyRecordBuffer(verifier))
            verified.push_back(at);
        else if (++failed >= kMaxBrokenFramesPerChunk)
            break;  // the reader's thread stops the chunk by then (a chunk of zeros is not walked)
    }
    return verified;
}

}  // namespace clastrace::traces::reader

namespace clastrace::traces {

using namespace reader;

void TraceReader::Impl::start_read_ahead(uint64_t offset, HeldChunks held) {
    drop_read_ahead();
    if (offset >= size || size - offset < format::kChunkHeaderSize ||
        chunks_of_broken_frames.contains(offset))
        return;
    const bool started = ahead.run([this, offset, held] {
        ReadAhead r;
        r.offset = offset;
        r.status = read_checked_payload(ahead_decoder, offset, &r.header, &r.error);
        if (r.status == ChunkStatus::kOk &&
            r.header.kind == static_cast<uint16_t>(format::ChunkKind::kRecords) &&
            r.header.raw_size <= kReadAheadMaxRawBytes) {
            r.status = decompress_payload(ahead_decoder, offset, r.header, &ahead_raw, &r.error);
            r.decompressed = r.status == ChunkStatus::kOk;
            if (r.decompressed) r.verified = verified_frames(ahead_raw);
            if (r.decompressed && options.decode_deltas_ahead)
                r.contents = decode_ahead(offset, ahead_raw, held);
        }
        return r;
    });
    if (started) ahead_started_at = offset;
}

void TraceReader::Impl::keep_loaded_as_older() {
    const uint64_t last = ahead_decoding.last_place_chunk;
    const bool deltas_likely =
        ahead_decoding.seen_delta || ++loads_without_delta <= kLoadsBeforeFirstDelta;
    if (deltas_likely && version_minor >= kFirstDeltaMinor && !raw.empty() && last != UINT64_MAX &&
        chunk_offset <= last && raw.size() <= kReadAheadMaxRawBytes) {
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

HeldChunks TraceReader::Impl::held_chunks(HeldChunk loaded) const {
    return {loaded,
            {HeldChunk{older_offset[0], &older_raw[0]}, HeldChunk{older_offset[1], &older_raw[1]}}};
}

std::optional<ReadAhead> TraceReader::Impl::take_read_ahead() {
    ahead_started_at = UINT64_MAX;
    std::optional<ReadAhead> r;
    try {
        r = ahead.get();
    } catch (const std::exception&) {
        return std::nullopt;
    }
    if (r->status != ChunkStatus::kOk && r->error.code == TraceErrorCode::kIoError)
        return std::nullopt;
    return r;
}

std::vector<AheadContents> TraceReader::Impl::decode_ahead(uint64_t offset, const ChunkBytes& r,
                                                           HeldChunks held) {
    std::vector<AheadContents> out;
    AheadDecoding& a = ahead_decoding;
    bool read_a_base = false;
    size_t next_frame = 0;
    uint32_t sure_to_break = 0;
    while (r.size() - next_frame >= format::kRecordFrameSize) {
        const auto at = static_cast<uint32_t>(next_frame);
        const uint32_t rsize = format::load<uint32_t>(r.data() + at);
        const uint32_t rkind = format::load<uint32_t>(r.data() + at + 4);
        if (rsize > r.size() - at - format::kRecordFrameSize) break;
        // The reader's thread stops a chunk at its kMaxBrokenFramesPerChunk-th broken frame, so
        // nothing past as many frames that must break (empty, or of no kind) is ever taken: a
        // chunk of zeros, 2^25 such frames, is not walked to its end (session 11's fuzzing).
        if ((rsize == 0 || rkind == 0) && ++sure_to_break >= kMaxBrokenFramesPerChunk) break;
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

bool TraceReader::Impl::decode_delta_ahead(uint64_t offset, const ChunkBytes& r, HeldChunks held,
                                           const ContentsRecord& c, AheadContents* made,
                                           bool* read_a_base) {
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

SharedBytes TraceReader::Impl::read_whole_ahead(uint64_t offset, const ChunkBytes& r,
                                                HeldChunks held, uint64_t hash, WholePlace place,
                                                bool* decompressed) {
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

void TraceReader::Impl::drop_read_ahead() {
    ahead.drop();
    ahead_started_at = UINT64_MAX;
}

}  // namespace clastrace::traces
