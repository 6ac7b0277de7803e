// SPDX-License-Identifier: Apache-2.0
// Fuzz target (docs/fuzzing.md): arbitrary bytes as a streams payload (chunk_streams.h) of a
// chunk whose raw size the first two bytes give, then the same bytes as a chunk to encode with
// cuts drawn from them, which must decode to themselves. Nothing may crash, hang, read or
// write outside the buffers, and a decoded chunk is exactly its raw size.
#include "chunk_streams.h"

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <vector>

using namespace clastrace::traces::format;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    static ZSTD_DCtx* dctx = ZSTD_createDCtx();
    static ZSTD_CCtx* cctx = ZSTD_createCCtx();
    if (size < 2) return 0;
    const size_t raw_size = size_t(data[0]) << 8 | data[1];
    std::vector<uint8_t> out(raw_size);
    (void)decode_streams_payload(dctx, data + 2, size - 2, out.data(), out.size());
    // Encode: cuts where the bytes say, in order and inside the chunk.
    std::vector<ContentCut> cuts;
    for (size_t at = 0, i = 0; i + 1 < size && cuts.size() < 64; i += 2) {
        // As the writer's: one cut per contents record, each taking kMinContentsFrameBytes.
        const size_t gap = (cuts.empty() ? 0 : kMinContentsFrameBytes) + data[i] % 32;
        const size_t length = data[i + 1];
        if (at + gap + length > size) break;
        const CutLayout layout = data[i] & 1 ? CutLayout::kBytePlanes : CutLayout::kAsIs;
        cuts.push_back({uint32_t(at + gap), uint32_t(length), layout});
        at += gap + length;
    }
    std::vector<uint8_t> payload;
    if (!encode_streams_payload(cctx, data, size, cuts, 1, 0, &payload).empty()) std::abort();
    std::vector<uint8_t> back(size);
    const StreamsProblem p =
        decode_streams_payload(dctx, payload.data(), payload.size(), back.data(), size);
    if (p) {
        std::fprintf(stderr, "a chunk encoded here does not decode: %s (payload byte %llu)\n",
                     p.what.c_str(), static_cast<unsigned long long>(p.at));
        std::abort();
    }
    if (std::memcmp(back.data(), data, size) != 0) std::abort();
    return 0;
}
