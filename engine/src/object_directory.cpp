// SPDX-License-Identifier: Apache-2.0
#include "clastrace/engine/object_directory.h"
#include "clastrace/common/debug_assert.h"
#include "clastrace/common/hex.h"

#include "clastrace/engine/blas.h"

#include <xxhash.h>

#include <cstring>
#include <sstream>

namespace clastrace::engine {
namespace {

using common::hex;

}  // namespace

uint64_t object_hash(std::span<const std::byte> bytes) {
    return XXH3_64bits(bytes.data(), bytes.size());
}

const char* object_type_name(ObjectType type) {
    switch (type) {
    case ObjectType::kTriangleCluster: return "CLAS";
    case ObjectType::kTriangleClusterTemplate: return "cluster template";
    case ObjectType::kClustersBottomLevel: return "clusters bottom-level acceleration structure";
    }
    return "unknown object";
}

ObjectLookup ObjectDirectory::lookup(const MemoryImage& memory, uint64_t address,
                                     ObjectType expected, bool any_type, FieldRef where) const {
    ObjectLookup r;
    if (lookup_log_) {
        std::lock_guard lock(lookup_log_->mutex);
        lookup_log_->addresses.push_back(address);
    }
    const char* want = any_type ? "cluster acceleration structure" : object_type_name(expected);
    if (address == 0) {
        r.error = std::string("address is 0, not a ") + want;
        return r;
    }
    auto live = live_.find(address);
    if (live == live_.end()) {
        auto moved = moved_to_.find(address);
        if (moved != moved_to_.end()) {
            r.error = "the object at " + hex(address) + " was moved away to " + hex(moved->second) +
                      "; no " + want + " is left there";
            return r;
        }
    }
    std::span<const std::byte> head;
    try {
        head = memory.read_bytes(address, 12, where);
    } catch (const MemoryFault& f) {
        r.error = "no " + std::string(want) + " at " + hex(address) + ": " + f.message;
        return r;
    }
    uint32_t magic, size;
    std::memcpy(&magic, head.data(), 4);
    std::memcpy(&size, head.data() + 8, 4);
    uint8_t type = uint8_t(head[4]);
    if (magic != kObjectMagic) {
        r.error = "no " + std::string(want) + " at " + hex(address) +
                  " (never built there, or overwritten: magic " + hex(magic) + ")";
        return r;
    }
    if (type < 1 || type > 3 || (!any_type && type != uint8_t(expected))) {
        r.error = "the object at " + hex(address) + " is a " +
                  (type >= 1 && type <= 3 ? object_type_name(ObjectType(type))
                                          : "object of unknown type") +
                  ", not a " + want;
        return r;
    }
    std::span<const std::byte> bytes;
    try {
        bytes = memory.read_bytes(address, size, where);
    } catch (const MemoryFault& f) {
        r.error = "the " + std::string(object_type_name(ObjectType(type))) + " header at " +
                  hex(address) + " claims " + std::to_string(size) + " bytes: " + f.message;
        return r;
    }
    std::string bad = type == uint8_t(ObjectType::kClustersBottomLevel)
                          ? read_bottom_level_header(bytes).error
                          : read_object_header(bytes).error;
    if (!bad.empty()) {
        r.error = "the " + std::string(object_type_name(ObjectType(type))) + " at " + hex(address) +
                  " is corrupt: " + bad;
        return r;
    }
    if (live != live_.end() &&
        (live->second.size != size || live->second.hash != object_hash(bytes))) {
        r.error = "the " + std::string(object_type_name(live->second.type)) + " built at " +
                  hex(address) + " has been overwritten since";
        return r;
    }
    r.bytes = bytes;
    r.type = ObjectType(type);
    return r;
}

namespace {
// A live object is one the engine built: one of the three types, its size what its header's
// 32-bit size field can hold.
bool live_entry_holds(ObjectType type, uint64_t size) {
    return type >= ObjectType::kTriangleCluster && type <= ObjectType::kClustersBottomLevel &&
           size != 0 && size <= UINT32_MAX;
}
}  // namespace

void ObjectDirectory::record_built(uint64_t address, ObjectType type,
                                   std::span<const std::byte> bytes) {
    CLASTRACE_DEBUG_ASSERT(live_entry_holds(type, bytes.size()));
    live_[address] = Live{type, uint32_t(bytes.size()), object_hash(bytes)};
    moved_to_.erase(address);
}

bool ObjectDirectory::same_entry(const ObjectDirectory& other, uint64_t address) const {
    auto live = live_.find(address), other_live = other.live_.find(address);
    if ((live == live_.end()) != (other_live == other.live_.end())) return false;
    if (live != live_.end())
        return live->second.type == other_live->second.type &&
               live->second.size == other_live->second.size &&
               live->second.hash == other_live->second.hash;
    // lookup() names where a moved object went: the destinations must agree too.
    auto moved = moved_to_.find(address), other_moved = other.moved_to_.find(address);
    if ((moved == moved_to_.end()) != (other_moved == other.moved_to_.end())) return false;
    return moved == moved_to_.end() || moved->second == other_moved->second;
}

void ObjectDirectory::copy_entry(const ObjectDirectory& other, uint64_t address) {
    auto it = other.live_.find(address);
    CLASTRACE_DEBUG_ASSERT(it != other.live_.end());
    if (it == other.live_.end()) return;
    live_[address] = it->second;
    moved_to_.erase(address);
}

bool ObjectDirectory::invariants_hold() const {
    for (const auto& [address, live] : live_)
        if (!live_entry_holds(live.type, live.size) || moved_to_.contains(address)) return false;
    return true;
}

void ObjectDirectory::forget(uint64_t begin, uint64_t end) {
    std::erase_if(live_,
                  [&](const auto& entry) { return entry.first >= begin && entry.first < end; });
    std::erase_if(moved_to_,
                  [&](const auto& entry) { return entry.first >= begin && entry.first < end; });
}

void ObjectDirectory::record_moved_away(uint64_t address, uint64_t new_address) {
    live_.erase(address);
    moved_to_[address] = new_address;
}

}  // namespace clastrace::engine
