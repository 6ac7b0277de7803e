// SPDX-License-Identifier: Apache-2.0
// What the trace reader's read-ahead task makes of the chunk it reads ahead: the chunk, its
// checks' verdict, and the real bytes of its contents (deltas XORed with the bases the task keeps),
// which the reader's thread takes once each record passed its checks.
#pragma once

#include "chunk_bytes.h"
#include "delta_bases.h"
#include "file_format.h"

#include <clastrace/traces/records.h>
#include <clastrace/traces/trace_error.h>

#include <array>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <unordered_map>
#include <vector>

namespace clastrace::traces::reader {

// How the chunk at an offset came out (the reader's and the task's verdict alike).
enum class ChunkStatus {
    kOk,
    kBadHeader,   // header unusable: look for the next chunk header byte by byte
    kBadPayload,  // header fine, payload not: skip exactly this chunk
    kTruncated,   // the file ends inside this chunk
    kOverBudget,  // decompressing it would pass TraceReaderOptions::max_raw_bytes: stop reading
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
    std::vector<uint32_t> verified;       // rising raw offsets of the frames the task verified
};

// The contents record in the frame at raw offset `at` of `raw`, verified; nullopt when the frame
// overruns the bytes or holds anything else.
std::optional<ContentsRecord> contents_in_frame(const ChunkBytes& raw, uint32_t at);

// The raw offsets of the frames of `raw` whose records pass the FlatBuffers verifier, walked as
// the reader's thread walks them: the task verifies a chunk's records, so that the reader's
// thread, the replay's, checks only what the verifier does not.
std::vector<uint32_t> verified_frames(const ChunkBytes& raw);

}  // namespace clastrace::traces::reader
