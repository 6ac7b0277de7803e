// SPDX-License-Identifier: Apache-2.0
#include "host_write_walk_cache.h"

#include <cstring>
#include <string_view>
#include <type_traits>

namespace clastrace::capture {
namespace {

// Past this many distinct commands kept, the cache starts over: an application recording new
// parameters every frame would otherwise grow it without end.
constexpr size_t kMaxWalks = 256;

static_assert(std::is_trivially_copyable_v<ClusterCommandParameters>,
              "walks are keyed by the parameters' bytes");

}  // namespace

bool HostWriteWalkCache::keepable(const ClusterCommandParameters& p) {
    return !(
        p.info.addressResolutionFlags &
        VK_CLUSTER_ACCELERATION_STRUCTURE_ADDRESS_RESOLUTION_INDIRECTED_SRC_INFOS_ARRAY_BIT_NV);
}

ClusterCommandParameters HostWriteWalkCache::key_of(const ClusterCommandParameters& p) {
    ClusterCommandParameters key;
    std::memcpy(static_cast<void*>(&key), &p, sizeof key);  // padding too: compared bytewise
    key.info.pNext = nullptr;
    key.info.input.pNext = nullptr;
    std::memset(static_cast<void*>(&key.info.input.opInput), 0, sizeof key.info.input.opInput);
    key.bottom_level_input.pNext = nullptr;
    key.triangle_cluster_input.pNext = nullptr;
    key.move_objects_input.pNext = nullptr;
    return key;
}

uint64_t HostWriteWalkCache::hash_of(const ClusterCommandParameters& key) {
    return std::hash<std::string_view>{}(
        std::string_view(reinterpret_cast<const char*>(&key), sizeof key));
}

const HostWriteWalkCache::Ranges* HostWriteWalkCache::find(
    const ClusterCommandParameters& p, uint64_t map_changes,
    const std::function<bool(const Read&)>& unchanged) const {
    const ClusterCommandParameters key = key_of(p);
    auto it = walks_.find(hash_of(key));
    if (it == walks_.end() || it->second.map_changes != map_changes ||
        std::memcmp(&it->second.key, &key, sizeof key) != 0)
        return nullptr;
    for (const Read& r : it->second.reads)
        if (!unchanged(r)) return nullptr;
    return &it->second.found;
}

const HostWriteWalkCache::Ranges& HostWriteWalkCache::keep(const ClusterCommandParameters& p,
                                                           uint64_t map_changes,
                                                           std::vector<Read> reads, Ranges found) {
    if (walks_.size() >= kMaxWalks) walks_.clear();
    const ClusterCommandParameters key = key_of(p);
    Walk& kept = walks_[hash_of(key)];
    kept = Walk{key, map_changes, std::move(reads), std::move(found)};
    return kept.found;
}

}  // namespace clastrace::capture
