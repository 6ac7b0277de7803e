// SPDX-License-Identifier: Apache-2.0
// Delta contents: decoding a delta in place in the loaded chunk (or taking the read-ahead task's
// result), the bases kept, and read_contents walking a chain of bases anywhere in the file.
#include "trace_reader_impl.h"

#include "byte_planes.h"

#include <algorithm>
#include <cstring>
#include <string>

namespace clastrace::traces::reader {

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

}  // namespace clastrace::traces::reader

namespace clastrace::traces {

using namespace reader;

bool TraceReader::Impl::decode_delta(const ContentsRecord& c, uint32_t at,
                                     SharedBytes* ahead_bytes) {
    auto problem = [&](TraceErrorCode code, const std::string& why) {
        report_record(code, at, [&] { return ": delta contents " + hex(c.hash) + " " + why; });
        return false;
    };
    if (!known_byte_planes(c.byte_planes))
        return problem(TraceErrorCode::kContentMismatch, unknown_planes(c.byte_planes));
    auto base = contents.find(c.base_hash);
    if (base == contents.end() || (!base->second.seen_in_scan && !seeked) ||
        !precedes(base->second.chunk_offset, base->second.raw_offset, chunk_offset, at))
        return problem(TraceErrorCode::kMissingContents,
                       "name the base " + hex(c.base_hash) + ", which no earlier record defines");
    const size_t n = c.size();
    if (base->second.size != n)
        return problem(TraceErrorCode::kContentMismatch,
                       "hold " + std::to_string(n) + " bytes but their base " + hex(c.base_hash) +
                           " holds " + std::to_string(base->second.size));
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

TraceError TraceReader::Impl::decode_delta_here(const ContentsRecord& c, uint8_t* data) {
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

const AheadContents* TraceReader::Impl::ahead_contents_at(uint32_t at) const {
    auto it = std::lower_bound(chunk_ahead.begin(), chunk_ahead.end(), at,
                               [](const AheadContents& a, uint32_t offset) {
                                   return a.raw_offset < offset;
                               });
    return it != chunk_ahead.end() && it->raw_offset == at ? &*it : nullptr;
}

bool TraceReader::Impl::ahead_used_my_base(const AheadContents& a, const ContentsRecord& c,
                                           const ContentPlace& base) const {
    if (!a.base || a.hash != c.hash || a.bytes->size != c.size()) return false;
    if (SharedBytes mine = resolved.find(c.base_hash)) return mine == a.base;
    return a.base_read_whole && a.base_chunk_offset == base.chunk_offset &&
           a.base_raw_offset == base.raw_offset;
}

SharedBytes TraceReader::Impl::ahead_whole_copy(const ContentsRecord& c, uint32_t at) const {
    const AheadContents* a = ahead_contents_at(at);
    return a && !a->base && a->hash == c.hash && a->bytes->size == c.size() ? a->bytes : nullptr;
}

SharedBytes TraceReader::Impl::copy_of(const uint8_t* data, size_t n) {
    std::shared_ptr<RealBytes> b = pool->take(n);
    if (n) std::memcpy(b->data.get(), data, n);
    return b;
}

void TraceReader::Impl::keep_real_bytes(uint64_t hash, const uint8_t* data, size_t n,
                                        SharedBytes ahead) {
    if (n > RealBytesCache::kBudgetBytes / 4 || resolved.by_hash.count(hash)) return;
    resolved.keep(hash, ahead ? std::move(ahead) : copy_of(data, n));
}

TraceError TraceReader::Impl::locate(uint64_t hash, bool may_evict_raw, ContentsRecord* found,
                                     ContentPlace* where, bool* real) {
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

SharedBytes TraceReader::Impl::known_real_bytes(uint64_t hash) const {
    if (SharedBytes kept = resolved.find(hash)) return kept;
    return read_back.find(hash);
}

bool TraceReader::Impl::key_holds(uint64_t hash, const ContentPlace& place, const uint8_t* data,
                                  size_t n, uint64_t seed) {
    if (place.key_checked) return true;
    if (format::content_key(data, n, seed, hash_bits) != hash) return false;
    contents.find(hash)->second.key_checked = true;  // `place` is its copy (locate)
    return true;
}

TraceError TraceReader::Impl::resolve_contents(uint64_t hash, std::vector<uint8_t>* out,
                                               bool may_evict_raw) {
    if (SharedBytes known = known_real_bytes(hash)) {
        out->assign(known->data.get(), known->data.get() + known->size);
        return {};
    }
    if (TraceError e = resolve_uncached(hash, out, may_evict_raw)) return e;
    if (!resolved.find(hash)) read_back.keep(hash, copy_of(out->data(), out->size()));
    return {};
}

TraceError TraceReader::Impl::read_contents_view(uint64_t hash, std::span<const uint8_t>* out) {
    *out = {};
    viewed = known_real_bytes(hash);
    if (!viewed) {
        if (TraceError e = resolve_contents(hash, &view_scratch, true)) return e;
        viewed = known_real_bytes(hash);  // kept there unless too big for them
    }
    *out = viewed ? std::span<const uint8_t>(viewed->data.get(), viewed->size)
                  : std::span<const uint8_t>(view_scratch);
    return {};
}

TraceError TraceReader::Impl::resolve_uncached(uint64_t hash, std::vector<uint8_t>* out,
                                               bool may_evict_raw) {
    std::vector<uint64_t> chain;  // deltas from `hash` back, the last one's base held whole
    uint64_t at = hash;
    for (;;) {
        if (SharedBytes known = known_real_bytes(at)) {
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
            if (!key_holds(at, place, out->data(), n, c.seed)) {
                return error(TraceErrorCode::kContentMismatch, place.chunk_offset,
                             "contents " + hex(at) + " hold bytes that hash differently");
            }
            break;
        }
        auto base = contents.find(c.base_hash);
        if (base == contents.end() || !precedes(base->second.chunk_offset, base->second.raw_offset,
                                                place.chunk_offset, place.raw_offset)) {
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
        if (!key_holds(chain[k], place, out->data(), n, c.seed)) {
            return error(TraceErrorCode::kContentMismatch, place.chunk_offset,
                         "delta contents " + hex(chain[k]) +
                             " decode to bytes that hash differently (a damaged base?)");
        }
        keep_real_bytes(chain[k], out->data(), n, nullptr);
    }
    return {};
}

}  // namespace clastrace::traces
