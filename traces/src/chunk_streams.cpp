// SPDX-License-Identifier: Apache-2.0
#include "chunk_streams.h"

#include "byte_planes.h"
#include "file_format.h"

#include <algorithm>
#include <cstring>

namespace clastrace::traces::format {

namespace {

// One entry of the cut table, read.
struct Cut {
    uint64_t at = 0, size = 0;  // in the raw bytes
    CutLayout layout = CutLayout::kAsIs;
};

// Working buffers of one reading thread (the reader's thread and its read-ahead task); big ones are given back after use so an odd huge chunk is not kept.
struct StreamsScratch {
    std::vector<uint8_t> records, contents;  // contents: the planes of a cut
    std::vector<Cut> cuts;
    void release_if_big() {
        constexpr size_t kKeep = 16u << 20;
        if (records.capacity() > kKeep) std::vector<uint8_t>().swap(records);
        if (contents.capacity() > kKeep) std::vector<uint8_t>().swap(contents);
    }
};
thread_local StreamsScratch scratch;

// The encoder's records stream (cut table and records), on the writer's compression thread.
struct EncodeScratch {
    UninitializedBytes records;
    void release_if_big() {
        if (records.capacity() > (16u << 20)) UninitializedBytes().swap(records);
    }
};
thread_local EncodeScratch encode_scratch;

void put_u32(uint8_t* to, uint32_t v) { std::memcpy(to, &v, 4); }
uint32_t get_u32(const uint8_t* from) {
    uint32_t v;
    std::memcpy(&v, from, 4);
    return v;
}


}  // namespace

std::string compress_frame(ZSTD_CCtx* cctx, const uint8_t* bytes, size_t size, int level,
                           int window_log, UninitializedBytes* out) {
    const size_t at = out->size();
    out->resize(at + ZSTD_compressBound(size));
    ZSTD_CCtx_reset(cctx, ZSTD_reset_session_and_parameters);
    ZSTD_CCtx_setParameter(cctx, ZSTD_c_compressionLevel, level);
    ZSTD_CCtx_setParameter(cctx, ZSTD_c_windowLog, window_log);
    const size_t n = ZSTD_compress2(cctx, out->data() + at, out->size() - at, bytes, size);
    if (ZSTD_isError(n)) return std::string("zstd compression failed: ") + ZSTD_getErrorName(n);
    out->resize(at + n);
    return {};
}

namespace {

// Decompresses the frame at payload[at, at + size) into `to`, which must come out at most
// `limit` bytes (the frame declares its size; a frame that does not is damage).
StreamsProblem decompress_frame(ZSTD_DCtx* dctx, const uint8_t* payload, size_t at, size_t size,
                                uint64_t limit, const char* which, std::vector<uint8_t>* to) {
    const unsigned long long declared = ZSTD_getFrameContentSize(payload + at, size);
    if (declared == ZSTD_CONTENTSIZE_UNKNOWN || declared == ZSTD_CONTENTSIZE_ERROR ||
        declared > limit) {
        return {std::string("the ") + which + " stream's zstd frame does not declare a size of " +
                    "at most " + std::to_string(limit) + " bytes",
                at};
    }
    to->resize(declared);
    const size_t got = ZSTD_decompressDCtx(dctx, to->data(), to->size(), payload + at, size);
    if (ZSTD_isError(got) || got != declared) {
        return {std::string("the ") + which + " stream does not decompress: " +
                    (ZSTD_isError(got) ? ZSTD_getErrorName(got) : "size differs"),
                at};
    }
    return {};
}

// Reads the cut table at the start of the records stream, and lays the records' bytes into
// `out` around the cuts. Checks that the cuts fit the streams and the chunk, and adds up the
// contents' bytes into `contents_size`.
StreamsProblem place_records(const std::vector<uint8_t>& records, uint64_t table_at, uint8_t* out,
                             size_t raw_size, std::vector<Cut>* cuts, uint64_t* contents_size) {
    auto problem = [&](std::string what) {
        return StreamsProblem{"the records stream's cut table: " + std::move(what), table_at};
    };
    if (records.size() < 4) return problem("no cut count");
    const uint64_t count = get_u32(records.data());
    if (count > (records.size() - 4) / kStreamsCutBytes)
        return problem(std::to_string(count) + " cuts do not fit in " +
                       std::to_string(records.size()) + " bytes");
    const uint8_t* entry = records.data() + 4;
    size_t from_records = 4 + count * kStreamsCutBytes, to = 0;
    cuts->resize(count);
    *contents_size = 0;
    for (uint64_t i = 0; i < count; ++i, entry += kStreamsCutBytes) {
        const uint64_t gap = get_u32(entry), size = get_u32(entry + 4), layout = get_u32(entry + 8);
        const std::string name = "cut " + std::to_string(i);
        if (gap > records.size() - from_records || gap > raw_size - to)
            return problem(name + " skips " + std::to_string(gap) + " record bytes, past the end");
        std::memcpy(out + to, records.data() + from_records, gap);
        from_records += gap;
        to += gap;
        if (size > raw_size - to)
            return problem(name + " of " + std::to_string(size) + " bytes at raw byte " +
                           std::to_string(to) + " runs past the chunk");
        if (layout != uint32_t(CutLayout::kBytePlanes) && layout != uint32_t(CutLayout::kAsIs))
            return problem(name + " has layout " + std::to_string(layout) +
                           ", which this reader does not know (0 or 4)");
        (*cuts)[i] = {to, size, CutLayout(layout)};
        *contents_size += size;
        to += size;
    }
    const size_t rest = records.size() - from_records;
    if (rest != raw_size - to)
        return problem("the streams hold " + std::to_string(to + rest) + " bytes for a chunk of " +
                       std::to_string(raw_size));
    std::memcpy(out + to, records.data() + from_records, rest);
    return {};
}

// Decompresses the contents stream's frame (payload[at, at + size)) straight into the cuts'
// places in `out`, a block at a time (zstd keeps its window itself); cuts in byte planes pass
// through `planes` first.
StreamsProblem place_contents(ZSTD_DCtx* dctx, const uint8_t* payload, size_t at, size_t size,
                              const std::vector<Cut>& cuts, uint64_t contents_size, uint8_t* out,
                              std::vector<uint8_t>* planes) {
    const unsigned long long declared = ZSTD_getFrameContentSize(payload + at, size);
    if (declared != contents_size)
        return {"the contents stream's zstd frame does not declare the cuts' " +
                    std::to_string(contents_size) + " bytes",
                at};
    ZSTD_DCtx_reset(dctx, ZSTD_reset_session_only);
    ZSTD_inBuffer in{payload + at, size, 0};
    size_t last = 1;  // zstd's last answer: 0 once the frame is decoded and flushed
    auto fill = [&](uint8_t* to, size_t n) -> StreamsProblem {
        ZSTD_outBuffer o{to, n, 0};
        while (o.pos < o.size) {
            const size_t before_in = in.pos, before_out = o.pos;
            const size_t r = last = ZSTD_decompressStream(dctx, &o, &in);
            if (ZSTD_isError(r))
                return {std::string("the contents stream does not decompress: ") +
                            ZSTD_getErrorName(r),
                        at};
            if (in.pos == before_in && o.pos == before_out)
                return {"the contents stream ends before its cuts are filled", at};
        }
        return {};
    };
    for (const Cut& c : cuts) {
        if (c.size == 0) continue;
        if (c.layout == CutLayout::kAsIs) {
            if (StreamsProblem p = fill(out + c.at, c.size)) return p;
            continue;
        }
        planes->resize(c.size);
        if (StreamsProblem p = fill(planes->data(), c.size)) return p;
        from_byte_planes(planes->data(), c.size, out + c.at);
    }
    // The frame must end here: zstd may still have its end to read after the last byte out.
    for (uint8_t extra = 0; last != 0;) {
        ZSTD_outBuffer o{&extra, 1, 0};
        const size_t before = in.pos;
        last = ZSTD_decompressStream(dctx, &o, &in);
        if (ZSTD_isError(last) || o.pos != 0 || (last != 0 && in.pos == before))
            return {"the contents stream does not end with its cuts", at};
    }
    if (in.pos != in.size) return {"the contents stream holds more than one frame", at};
    return {};
}

}  // namespace

bool planes_pay(const uint8_t* bytes, size_t size) {
    const size_t words = size / 4;
    if (words < 16) return false;
    const size_t step = (words + 4095) / 4096;
    uint32_t high_bytes[256] = {};
    size_t sampled = 0, nonzero = 0;
    for (size_t i = 0; i < words; i += step, ++sampled) {
        const uint32_t w = get_u32(bytes + 4 * i);
        ++high_bytes[w >> 24];
        nonzero += w != 0;
    }
    uint32_t most = 0;
    for (uint32_t n : high_bytes) most = std::max(most, n);
    return uint64_t{most} * 16 >= sampled * 15 && nonzero * 2 >= sampled;
}

bool is_streams_payload(const uint8_t* payload, size_t size) {
    return size >= 4 && get_u32(payload) == kStreamsMagic;
}

std::string encode_split_chunk(ZSTD_CCtx* cctx, const SplitChunk& chunk, int zstd_level,
                               int zstd_window_log, UninitializedBytes* out) {
    // The records stream: the cut table, then the records' bytes.
    UninitializedBytes& records = encode_scratch.records;
    const size_t table = 4 + chunk.cuts.size() * kStreamsCutBytes;
    records.resize(table + chunk.records.size());
    put_u32(records.data(), static_cast<uint32_t>(chunk.cuts.size()));
    uint8_t* entry = records.data() + 4;
    size_t from = 0;
    for (const ContentCut& c : chunk.cuts) {
        put_u32(entry, c.offset - static_cast<uint32_t>(from));
        put_u32(entry + 4, c.size);
        put_u32(entry + 8, static_cast<uint32_t>(c.layout));
        entry += kStreamsCutBytes;
        from = c.offset + c.size;
    }
    if (!chunk.records.empty())
        std::memcpy(records.data() + table, chunk.records.data(), chunk.records.size());

    out->resize(kStreamsHeaderSize);
    std::string problem =
        compress_frame(cctx, records.data(), records.size(), zstd_level, zstd_window_log, out);
    const size_t records_frame = out->size() - kStreamsHeaderSize;
    if (problem.empty())
        problem = compress_frame(cctx, chunk.contents.data(), chunk.contents.size(), zstd_level,
                                 zstd_window_log, out);
    encode_scratch.release_if_big();
    if (!problem.empty()) return problem;
    put_u32(out->data(), kStreamsMagic);
    put_u32(out->data() + 4, static_cast<uint32_t>(records_frame));
    put_u32(out->data() + 8,
            static_cast<uint32_t>(out->size() - kStreamsHeaderSize - records_frame));
    put_u32(out->data() + 12, 0);
    return {};
}

void join_split_chunk(const SplitChunk& chunk, UninitializedBytes* raw) {
    raw->resize(chunk.raw_size());
    const uint8_t* records = chunk.records.data();
    const uint8_t* contents = chunk.contents.data();
    size_t to = 0;
    for (const ContentCut& c : chunk.cuts) {
        const size_t gap = c.offset - to;
        if (gap) std::memcpy(raw->data() + to, records, gap);
        records += gap;
        if (c.layout == CutLayout::kBytePlanes)
            from_byte_planes(contents, c.size, raw->data() + c.offset);
        else if (c.size)
            std::memcpy(raw->data() + c.offset, contents, c.size);
        contents += c.size;
        to = c.offset + c.size;
    }
    const size_t rest = raw->size() - to;
    if (rest) std::memcpy(raw->data() + to, records, rest);
}

std::string encode_streams_payload(ZSTD_CCtx* cctx, const uint8_t* raw, size_t raw_size,
                                   std::span<const ContentCut> cuts, int zstd_level,
                                   int zstd_window_log, std::vector<uint8_t>* out) {
    size_t cut_bytes = 0;
    for (const ContentCut& c : cuts) cut_bytes += c.size;
    UninitializedBytes records(raw_size - cut_bytes), contents(cut_bytes);
    uint8_t* to_records = records.data();
    uint8_t* to_contents = contents.data();
    size_t from = 0;
    for (const ContentCut& c : cuts) {
        const size_t gap = c.offset - from;
        if (gap) std::memcpy(to_records, raw + from, gap);
        to_records += gap;
        if (c.layout == CutLayout::kBytePlanes)
            to_byte_planes(raw + c.offset, c.size, to_contents);
        else if (c.size)
            std::memcpy(to_contents, raw + c.offset, c.size);
        to_contents += c.size;
        from = c.offset + c.size;
    }
    if (raw_size > from) std::memcpy(to_records, raw + from, raw_size - from);
    UninitializedBytes payload;
    std::string problem = encode_split_chunk(cctx, SplitChunk{records, contents, cuts}, zstd_level,
                                             zstd_window_log, &payload);
    out->assign(payload.begin(), payload.end());
    return problem;
}

StreamsProblem decode_streams_payload(ZSTD_DCtx* dctx, const uint8_t* payload, size_t size,
                                      uint8_t* out, size_t raw_size) {
    if (size < kStreamsHeaderSize || get_u32(payload) != kStreamsMagic)
        return {"not a streams payload (no 16-byte header with the magic CLTS)", 0};
    const uint64_t records_frame = get_u32(payload + 4), contents_frame = get_u32(payload + 8);
    if (get_u32(payload + 12) != 0) return {"the streams header's reserved word is not 0", 12};
    if (kStreamsHeaderSize + records_frame + contents_frame != size) {
        return {"the streams header's frames of " + std::to_string(records_frame) + " and " +
                    std::to_string(contents_frame) + " bytes do not fill the payload's " +
                    std::to_string(size) + " bytes",
                4};
    }
    // One cut per contents record, each framed in at least kMinContentsFrameBytes raw bytes.
    const uint64_t most_cuts = raw_size / kMinContentsFrameBytes + 1;
    StreamsProblem p =
        decompress_frame(dctx, payload, kStreamsHeaderSize, records_frame,
                         4 + most_cuts * kStreamsCutBytes + raw_size, "records", &scratch.records);
    std::vector<Cut>& cuts = scratch.cuts;
    uint64_t contents_size = 0;
    if (!p)
        p = place_records(scratch.records, kStreamsHeaderSize, out, raw_size, &cuts,
                          &contents_size);
    if (!p)
        p = place_contents(dctx, payload, kStreamsHeaderSize + records_frame, contents_frame, cuts,
                           contents_size, out, &scratch.contents);
    scratch.release_if_big();
    return p;
}

}  // namespace clastrace::traces::format
