// SPDX-License-Identifier: Apache-2.0
// The guarded submissions' input walks, kept for the next submission of a cluster command with the
// same parameters (a frame loop records the same builds over the same buffers every frame). A
// guarded walk's course depends on nothing but the command's parameters, the bytes it copied on
// its way (the count, indirect cells, the src infos entries; the ranges it only lists it never
// reads) and where the memory map places addresses. So when the parameters are equal, the map has
// not changed and each of those reads gives the bytes it gave before, the walk would find the
// same ranges in the same places: they are reused, without walking or resolving. The bytes are
// compared, not taken as unchanged from the page guard: a device write (a GPU copy into the src
// infos) changes them without a fault.
#pragma once

#include "clastrace/capture/capture_records.h"
#include "clastrace/capture/device_memory_map.h"
#include "host_write_device_writes.h"

#include <cstdint>
#include <functional>
#include <unordered_map>
#include <vector>

namespace clastrace::capture {

class HostWriteWalkCache {
public:
    // A read the walk made that steered it: where, and the bytes it got.
    struct Read {
        VkDeviceAddress address = 0;
        std::vector<uint8_t> bytes;
    };
    // A range the walk found, placed in its allocation and the layer's mapping.
    struct Found {
        VkDeviceAddress address = 0;
        uint64_t size = 0;
        MemorySpan span;
        const uint8_t* host = nullptr;
        TrackedMemory memory;
    };
    // The ranges a walk found in one allocation, as the page guard holds them: the pages of the
    // ranges that lie wholly on pages inside the allocation's bytes (sorted, each once), those
    // ranges, and the others, which are hashed (indices into the walk's `found`).
    struct Group {
        TrackedMemory memory;
        std::vector<uintptr_t> pages;
        std::vector<uint32_t> on_pages, hashed;
    };
    // What a walk found, and the same grouped by allocation: a walk kept is reused whole, so a
    // resubmitted command costs no per-range work before its pages are watched.
    struct Ranges {
        std::vector<Found> found;
        std::vector<Group> groups;
    };

    // Whether a walk of `p` may be kept: one whose src infos entries lie behind an indirection
    // reads them through views, which the reads do not record.
    static bool keepable(const ClusterCommandParameters& p);
    // The ranges of the walk kept for parameters equal to `p` under `map_changes`
    // (DeviceMemoryMap::changes), if `unchanged` says each of its reads still gives its bytes;
    // null otherwise.
    const Ranges* find(const ClusterCommandParameters& p, uint64_t map_changes,
                       const std::function<bool(const Read&)>& unchanged) const;
    // Keeps a walk of `p` (replacing the one kept for equal parameters) and returns its ranges as
    // kept. A walk kept before the map changed (memory freed, say) is never found again.
    const Ranges& keep(const ClusterCommandParameters& p, uint64_t map_changes,
                       std::vector<Read> reads, Ranges found);

private:
    struct Walk {
        ClusterCommandParameters key;  // normalized: see key_of
        uint64_t map_changes = 0;
        std::vector<Read> reads;
        Ranges found;
    };
    // `p` with its pointers cleared (the application's, meaningless to the walk), compared bytewise.
    static ClusterCommandParameters key_of(const ClusterCommandParameters& p);
    static uint64_t hash_of(const ClusterCommandParameters& key);
    std::unordered_map<uint64_t, Walk> walks_;  // key's hash -> the walk kept
};

}  // namespace clastrace::capture
