// SPDX-License-Identifier: Apache-2.0
// Which acceleration structures a consumer (vkCmdTraceRays*, a dispatch or draw whose shaders
// use ray queries) reads: the structure it binds and everything reachable from it. A top
// level reaches the bottom levels its instances named at its last build (not what the
// instance buffer holds now: the build copied the references); a cluster bottom level
// reaches the CLAS its cluster references named, read from the engine's object bytes, which
// are what its last build wrote. The closure is kept here only (docs/replay.md, "Consumers").
#pragma once

#include <clastrace/replay/sync_types.h>

#include <cstdint>
#include <functional>
#include <optional>
#include <span>
#include <string>
#include <unordered_map>
#include <unordered_set>
#include <vector>

namespace clastrace::replay::detail {

// VkAccelerationStructureInstanceKHR (and VK_NV_ray_tracing's instance, the same 64 bytes):
// accelerationStructureReference is the last 8 bytes, a device address (KHR) or the handle
// vkGetAccelerationStructureHandleNV answered (NV).
inline constexpr uint64_t kInstanceBytes = 64;
inline constexpr uint64_t kInstanceReferenceOffset = 56;

// The references of `count` instances packed in `bytes` (arrayOfPointers false, NV builds),
// in instance order; instances past the end of `bytes` are left out.
std::vector<uint64_t> packed_instance_references(std::span<const uint8_t> bytes, uint32_t count);

// A cluster bottom level as the engine built it: its bytes and the CLAS it names.
struct ClusterBottomLevel {
    AddressRange range;
    struct Cluster {
        uint32_t reference_index = 0;  // index into the build's clusterReferences
        AddressRange range;
    };
    std::vector<Cluster> clusters;
};

// One structure a consumer reads, in the synchronization model's addresses.
struct ReachedStructure {
    uint64_t handle = 0;  // 0: a cluster object, known by its address only
    AddressRange range;
    // How the consumer reaches it, e.g. "top level 0xa5003 > instance 2: bottom level
    // 0xa5001" or "... > instance 0: cluster bottom level 0x20000 > cluster 5: CLAS 0x20400".
    std::string path;
    // False for a created structure that no command of the trace has built, copied or
    // deserialized into since its creation (on_written): nothing a consumer could read.
    bool written = true;
};

class StructureReachability {
public:
    // Where an object's bytes are (null when it is not bound); a cluster bottom level at a
    // device address (nullopt when none was built there). Both are asked at each consumer.
    using ObjectRange = std::function<std::optional<AddressRange>(uint64_t handle)>;
    using ClusterLookup = std::function<std::optional<ClusterBottomLevel>(uint64_t address)>;
    StructureReachability(ObjectRange object_range, ClusterLookup cluster_lookup)
        : object_range_(std::move(object_range)), cluster_lookup_(std::move(cluster_lookup)) {}

    // vkCreateAccelerationStructure*: `reference` is what instances and bindings name it by
    // (the NV handle, or the KHR device address; 0 when the trace holds none).
    void on_created(uint64_t handle, uint64_t reference);
    void on_destroyed(uint64_t handle);
    // A command of the trace (replayed or not) built, copied or deserialized into `handle`.
    void on_written(uint64_t handle) { written_.insert(handle); }
    bool written(uint64_t handle) const { return written_.count(handle) != 0; }
    // A top-level build of `handle` whose instances held `references`, in instance order.
    void on_top_level_built(uint64_t handle, std::vector<uint64_t> references);

    // Every structure reachable from a binding (its handle, or 0 and its address), the bound
    // structure first, each once. `root` names the binding in the paths.
    std::vector<ReachedStructure> reach(uint64_t handle, uint64_t address,
                                        const std::string& root) const;
    // The handle an instance reference or a binding's address names, if one was created.
    std::optional<uint64_t> handle_of(uint64_t reference) const;
    // Top levels whose last build named `handle` (for findings about a structure in use).
    std::vector<uint64_t> top_levels_naming(uint64_t handle) const;

private:
    void add_object(uint64_t handle, const std::string& path,
                    std::vector<ReachedStructure>* out) const;
    void add_clusters(const ClusterBottomLevel& blas, uint64_t address, const std::string& path,
                      std::vector<ReachedStructure>* out) const;
    void add_reference(uint64_t reference, const std::string& path,
                       std::vector<ReachedStructure>* out) const;

    ObjectRange object_range_;
    ClusterLookup cluster_lookup_;
    std::unordered_map<uint64_t, uint64_t> by_reference_;            // reference -> handle
    std::unordered_map<uint64_t, uint64_t> reference_of_;            // handle -> reference
    std::unordered_map<uint64_t, std::vector<uint64_t>> instances_;  // top level -> references
    std::unordered_set<uint64_t> written_;                           // see on_written
};

}  // namespace clastrace::replay::detail
