// SPDX-License-Identifier: Apache-2.0
// Pieces the NV build, update and serialization share.
#pragma once

#include "clastrace/common/uninitialized_allocator.h"
#include "clastrace/engine/nv_format.h"
#include "geometry/box.h"

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <span>
#include <vector>

namespace clastrace::engine::nv {

using geometry::Box;

// Binned SAH tree over `boxes` (all valid): nodes in depth-first order (left child at
// index + 1, right child at NvNode::first), leaves of up to kNvMaxLeafSize; `order` is
// the item order leaves refer to. Deterministic: same boxes, same tree.
struct Tree {
    std::vector<NvNode> nodes;
    // Written whole by the builders: no first pass of zeros.
    std::vector<uint32_t, common::UninitializedAllocator<uint32_t>> order;
};
// kSah: binned SAH (the default). kMorton: linear BVH over sorted Morton codes, several
// times faster to build and slower to trace (VK_BUILD_ACCELERATION_STRUCTURE_PREFER_FAST_BUILD_BIT_NV).
enum class TreeQuality { kSah, kMorton };
// What an SAH tree is for, which sets how it ends its branches and chooses its splits.
// kBottom: every range of up to kNvMaxLeafSize items is a leaf (the traversal tests a leaf's
// items four at once and merges any stored subtree of up to twelve contiguous records into
// one leaf, so splitting such a range buys nothing), and every larger range is binned, Embree's
// way. kTop: the SAH weighs a leaf against its best split at one item per intersection, and
// ranges of up to 16 items take the exact sweep (top levels are small, and their leaves become
// chains of single instances, each costing a bottom-level walk). Morton trees always end at
// kNvMaxLeafSize items.
enum class TreeLevel { kBottom, kTop };
// `centroids`, where the caller took them while it had the boxes at hand, are the bounds of
// the boxes' centroids (lo and hi halved, then added); the Morton build reads them instead of
// taking a pass over the boxes for them.
Tree build_tree(std::span<const Box> boxes, TreeQuality quality = TreeQuality::kSah,
                TreeLevel level = TreeLevel::kBottom, const Box* centroids = nullptr);

// Gives a tree's arrays back once its object is written: the thread's next build_tree grows
// its tree in them, on pages already faulted in.
void recycle_tree(Tree&& tree);

// Working arrays the builds keep per thread between builds (build_tree's, the gather's): a
// fresh page costs a fault and a clear, and a large fresh array faults in every page each
// build. What one thread keeps of one kind, and what all threads keep together, is capped: a
// 16-thread replay once held up to 1 GiB of them between builds.
constexpr size_t kKeptBytesPerThread = size_t(64) << 20;  // ~1.2M Morton items
constexpr size_t kAllKeptBytes = size_t(128) << 20;       // every thread, every kind
// Counts `bytes` as kept; false (nothing counted) when that would pass a cap: drop them.
bool claim_kept_bytes(size_t bytes);
void release_kept_bytes(size_t bytes);

// Recomputes every node box from its items (leaf) or children, bottom-up. `item_box(i)`
// is the box of record i (the leaf ranges index records directly).
template <class ItemBox>
void refit_tree(std::span<NvNode> nodes, ItemBox item_box) {
    for (size_t k = nodes.size(); k-- > 0;) {
        NvNode& n = nodes[k];
        Box b = Box::empty();
        if (n.count == 0) {
            for (uint32_t c : {uint32_t(k + 1), n.first}) {
                const NvNode& child = nodes[c];
                b.grow(Box{{child.bounds_min[0], child.bounds_min[1], child.bounds_min[2]},
                           {child.bounds_max[0], child.bounds_max[1], child.bounds_max[2]}});
            }
        } else {
            for (uint32_t i = 0; i < n.count; ++i) b.grow(item_box(n.first + i));
        }
        for (int a = 0; a < 3; ++a) {
            n.bounds_min[a] = b.lo[a];
            n.bounds_max[a] = b.hi[a];
        }
    }
}

Box triangle_box(const float v[9]);
// The world box of `local` under a 3x4 row-major transform (all 8 corners, in double,
// rounded outwards to float).
Box transform_box(const Box& local, const float m[12]);

}  // namespace clastrace::engine::nv
