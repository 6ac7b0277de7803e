// SPDX-License-Identifier: Apache-2.0
// Which engine objects are alive where. A device address "holds a CLAS" only while the
// object built there is intact: a move (without noMoveOverlap) retires its source, and
// any later write over the bytes changes their hash. Replay keeps one directory across
// commands; execute() consults it for every object an op reads and updates it after
// the op's writes land.
//
// An address the directory has never seen is judged by its bytes alone (a header that
// checks out), so objects already in a trace's first memory snapshot still work.
#pragma once

#include "clastrace/engine/cluster_format.h"
#include "clastrace/engine/memory_image.h"

#include <cstddef>
#include <cstdint>
#include <mutex>
#include <span>
#include <string>
#include <unordered_map>
#include <vector>

namespace clastrace::engine {

struct ObjectLookup {
    std::span<const std::byte> bytes;  // the whole object when found
    ObjectType type{};
    std::string error;  // empty when found; otherwise why the address holds no such object
    bool found() const { return error.empty(); }
};

class ObjectDirectory {
public:
    // The object at `address`, which must be of type `expected` (or any type when
    // `expected` is nullopt-like 0). Reads through `memory`; never throws.
    ObjectLookup lookup(const MemoryImage& memory, uint64_t address, ObjectType expected,
                        bool any_type, FieldRef where) const;

    // After `bytes` were written at `address` by op `op_index` of command `command`.
    void record_built(uint64_t address, ObjectType type, std::span<const std::byte> bytes);
    // After a move without noMoveOverlap: the source no longer holds an object.
    void record_moved_away(uint64_t address, uint64_t new_address);

    // After the memory [begin, end) was freed (a destroyed buffer): nothing lives there now.
    void forget(uint64_t begin, uint64_t end);

    size_t live_count() const { return live_.size(); }

    // For a build run on a directory of its own and checked against this one later (replay's
    // runs ahead): every address lookup() is asked about while `log` is set goes into it, from
    // any thread; nullptr stops.
    struct LookupLog {
        std::mutex mutex;
        std::vector<uint64_t> addresses;
    };
    void log_lookups(LookupLog* log) { lookup_log_ = log; }
    // True when lookup() judges `address` here as it does in `other` for the same bytes: both
    // know nothing of it, or both hold the same live object, or both moved it to the same place.
    bool same_entry(const ObjectDirectory& other, uint64_t address) const;
    // Records `other`'s live object at `address` here, as record_built would for the same
    // bytes (which the caller has copied), without hashing them again.
    void copy_entry(const ObjectDirectory& other, uint64_t address);

    // No address is both alive and moved away, and every live object has a known type and the
    // size it was built with. O(objects): for tests; the record_* calls check the entry they
    // change when debug checks are on (clastrace/common/debug_assert.h).
    bool invariants_hold() const;

private:
    friend struct ObjectDirectoryTestAccess;  // tests only: breaks a directory on purpose

    struct Live {
        ObjectType type;
        uint32_t size;
        uint64_t hash;
    };
    std::unordered_map<uint64_t, Live> live_;
    std::unordered_map<uint64_t, uint64_t> moved_to_;  // retired source -> destination
    LookupLog* lookup_log_ = nullptr;
};

uint64_t object_hash(std::span<const std::byte> bytes);
const char* object_type_name(ObjectType type);

}  // namespace clastrace::engine
