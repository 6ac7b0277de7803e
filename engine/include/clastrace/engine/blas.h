// SPDX-License-Identifier: Apache-2.0
// The bottom-level cluster acceleration structure (BLAS): a BVH over the bounds of the
// CLAS it references, leaves naming each CLAS by device address (as the GPU object
// does), so a BLAS moves by plain copy while the CLAS it names must stay put.
//
// Byte format (little-endian, position independent, docs/engine-blas-formats.md):
//   BottomLevelHeader (64 B) | node_count BottomLevelNode (32 B) | reference_count ClusterReference (16 B)
// Nodes are in depth-first order, node 0 the root; an interior node's children are
// `first` and `first + 1`; a leaf covers references [first, first + count).
#pragma once

#include "clastrace/engine/cluster_format.h"
#include "clastrace/engine/finding.h"
#include "clastrace/engine/memory_image.h"
#include "clastrace/engine/object_directory.h"
#include "clastrace/engine/traversal.h"

#include <cstddef>
#include <cstdint>
#include <functional>
#include <optional>
#include <span>
#include <string>
#include <vector>

namespace clastrace::engine {

inline constexpr uint8_t kBottomLevelFormatVersion = 1;
inline constexpr uint32_t kBottomLevelMaxLeafSize = 4;

// The first 12 bytes match ObjectHeader (magic, type, version, flags, size), so any
// engine object is sized from its first bytes alone.
struct BottomLevelHeader {
    uint32_t magic;            // kObjectMagic
    uint8_t object_type;       // ObjectType::ClustersBottomLevel
    uint8_t format_version;    // kBottomLevelFormatVersion
    uint16_t header_flags;     // 0
    uint32_t object_size;      // whole object, header included
    uint32_t reference_count;  // references stored (valid, non-empty clusters)
    uint32_t node_count;       // 0 when reference_count == 0
    uint32_t nodes_offset;
    uint32_t references_offset;
    uint32_t input_reference_count;  // clusterReferencesCount as given
    float bounds_min[3];
    float bounds_max[3];
    uint32_t reserved[2];
};
static_assert(sizeof(BottomLevelHeader) == 64);

struct BottomLevelNode {
    float bounds_min[3];
    uint32_t first;  // interior: left child index; leaf: first reference
    float bounds_max[3];
    uint32_t count;  // 0: interior; 1..kBottomLevelMaxLeafSize: leaf
};
static_assert(sizeof(BottomLevelNode) == 32);

struct ClusterReference {
    uint64_t clas_address;     // device address of the CLAS
    uint32_t reference_index;  // index into clusterReferences as the app gave it
    uint32_t cluster_id;       // the CLAS's clusterID when built (for hit reports)
};
static_assert(sizeof(ClusterReference) == 16);

// One cluster to place in the BVH.
struct ClusterBox {
    float bounds_min[3];
    float bounds_max[3];
    uint64_t clas_address;
    uint32_t reference_index;
    uint32_t cluster_id;
};

// Builds the object bytes (binned SAH, deterministic: same boxes -> same bytes).
// Boxes with min > max on any axis (empty clusters) are left out. The result is empty
// when the object would exceed 4 GiB (the caller reports it).
std::vector<std::byte> build_bottom_level(std::span<const ClusterBox> clusters,
                                          uint32_t input_reference_count);

// Worst-case object size for `cluster_count` references (every cluster a leaf).
uint64_t bottom_level_size_bound(uint64_t cluster_count);

struct BottomLevelCheck {
    std::optional<BottomLevelHeader> header;
    std::string error;
};
// Checks magic, type, version, and that nodes and references lie inside the object and
// inside `bytes`, and that every node index / reference range is in bounds.
BottomLevelCheck read_bottom_level_header(std::span<const std::byte> bytes);

// A hit inside a BLAS: the CLAS traversal's hit plus which reference it came through.
struct BottomLevelHit {
    Hit hit{};
    uint32_t reference_index = 0;
    uint64_t clas_address = 0;
};

// Traces a ray through the BLAS at `blas_address`, descending into each CLAS with
// the CLAS traversal. A reference whose address no longer holds a CLAS (judged by
// `directory` when given, else by the bytes) is skipped and reported once per reference
// in `findings` (rule kRuleStaleClusterReference). An address that holds no BLAS gives a
// miss and one finding.
BottomLevelHit trace_bottom_level_closest(const MemoryImage& memory, uint64_t blas_address,
                                          const Ray& ray, uint32_t ray_flags,
                                          const ObjectDirectory* directory = nullptr,
                                          std::vector<Finding>* findings = nullptr,
                                          TraversalMode mode = TraversalMode::kDouble);
bool trace_bottom_level_any(const MemoryImage& memory, uint64_t blas_address, const Ray& ray,
                            uint32_t ray_flags, const ObjectDirectory* directory = nullptr,
                            std::vector<Finding>* findings = nullptr,
                            TraversalMode mode = TraversalMode::kDouble);

// The same traversal over a BLAS already read out of memory and checked with
// read_bottom_level_header (a KHR or NV top level copies what it reaches once, nv_trace.h):
// `clas_at` gives the bytes of the CLAS a reference names, or an empty span when that
// address holds none (the reference is skipped). `first_hit`: stop at the first accepted hit.
BottomLevelHit trace_bottom_level_bytes(
    std::span<const std::byte> blas,
    const std::function<std::span<const std::byte>(uint64_t clas_address)>& clas_at, const Ray& ray,
    uint32_t ray_flags, bool first_hit, TraversalMode mode = TraversalMode::kDouble);

// The same over CLASes the caller opened once (open_clas): `clas_at` gives the view a
// reference names, or nullptr (skipped). The bytes form above checks each CLAS on every visit
// (read_object_header: every local index and node link), which is most of a ray's time when
// the caller has checked them already.
BottomLevelHit trace_bottom_level_views(
    std::span<const std::byte> blas,
    const std::function<const ClasView*(uint64_t clas_address)>& clas_at, const Ray& ray,
    uint32_t ray_flags, bool first_hit, TraversalMode mode = TraversalMode::kDouble);

// The reference for the walk above: every referenced CLAS traced with
// trace_closest_exhaustive (every triangle, no box), no BLAS box either. The closest hit by its
// float t, ties to the lowest reference index; the walk gives the same hit.
BottomLevelHit trace_bottom_level_bytes_exhaustive(
    std::span<const std::byte> blas,
    const std::function<std::span<const std::byte>(uint64_t clas_address)>& clas_at, const Ray& ray,
    uint32_t ray_flags, TraversalMode mode = TraversalMode::kDouble);

inline constexpr const char* kRuleStaleClusterReference =
    "CLASTRACE-cluster-reference-holds-no-clas";
inline constexpr const char* kRuleNotABottomLevel = "CLASTRACE-not-a-clusters-bottom-level";

}  // namespace clastrace::engine
