// SPDX-License-Identifier: Apache-2.0
// Binned SAH over cluster boxes (the engine's SAH core, geometry/binned_sah.h): 16 bins on
// each axis of the centroid bounds, object-median fallback when centroids coincide. The
// core's top-down builder lays the nodes out in sibling pairs; large subtrees split their
// halves across threads (TBB), and the bytes never depend on the thread count.
#include "clastrace/engine/blas.h"

#include "geometry/binned_sah.h"
#include "geometry/box.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <limits>

namespace clastrace::engine {
namespace {

// Descending into a CLAS costs a few node visits.
constexpr geometry::SahParams kSah{16, 1.0, 4.0, kBottomLevelMaxLeafSize};
constexpr int kBins = kSah.max_bins;

using geometry::Box;

struct Item {
    Box box;
    float centroid[3];
    uint32_t source;  // index into the caller's span
};

bool valid_box(const ClusterBox& c) {
    for (int a = 0; a < 3; ++a) {
        if (!(c.bounds_min[a] <= c.bounds_max[a])) return false;  // also rejects NaN
    }
    return true;
}


// A node's items [begin, end) with their box and centroid bounds.
struct Range {
    uint32_t begin = 0, end = 0;
    Box bounds, centroids;
    uint32_t count() const { return end - begin; }
};

struct Bin {
    Box box, centroids;
    uint32_t count = 0;
};

// The bin of a centroid `offset` past the centroid bounds' low corner. Clamped in float before
// the conversion: a denormal extent makes the scale infinite, and offset * scale is then
// infinite or NaN, whose conversion to int is undefined (a wild bin index). NaN goes to bin 0.
int bin_of(float offset, float scale) {
    const float x = offset * scale;
    if (!(x > 0.0f)) return 0;
    return x >= float(kBins - 1) ? kBins - 1 : int(x);
}

// SAH over 16 bins on each axis, one pass over the items; partitions [begin, end) in place.
// Returns false for a leaf.
bool split_node(std::vector<Item>& items, const Range& range, Range* left, Range* right) {
    const uint32_t begin = range.begin, end = range.end, count = range.count();
    const Box &bounds = range.bounds, &centroids = range.centroids;
    if (count == 1) return false;
    std::array<std::array<Bin, kBins>, 3> bins;
    float scale[3];
    bool axis_ok[3];
    for (int a = 0; a < 3; ++a) {
        float extent = centroids.hi[a] - centroids.lo[a];
        axis_ok[a] = extent > 0.0f && std::isfinite(extent);
        scale[a] = axis_ok[a] ? float(kBins) / extent : 0.0f;
    }
    for (uint32_t i = begin; i < end; ++i) {
        const Item& it = items[i];
        for (int a = 0; a < 3; ++a) {
            if (!axis_ok[a]) continue;
            Bin& bin = bins[a][bin_of(it.centroid[a] - centroids.lo[a], scale[a])];
            bin.box.grow(it.box);
            bin.centroids.grow_point(it.centroid);
            ++bin.count;
        }
    }
    const geometry::SahSplit<float> best = geometry::cheapest_split<float, kBins>(
        kBins, axis_ok, [&](int a, int k) -> const Box& { return bins[a][k].box; },
        [&](int a, int k) { return bins[a][k].count; }, Box::empty(),
        [](const Box& b) { return b.half_area<float>(); });
    const int best_axis = best.axis, best_plane = best.bin;
    if (best_axis >= 0) {
        // The leaf rule in float, normalized by the parent's area (a zero or infinite area
        // compares the split as costing a leaf).
        const float traversal_cost = float(kSah.traversal_cost),
                    cluster_cost = float(kSah.intersection_cost);
        const float parent_area = bounds.half_area<float>();
        float split_cost = traversal_cost + (parent_area > 0.0f && std::isfinite(parent_area)
                                                 ? cluster_cost * best.cost / parent_area
                                                 : cluster_cost * float(count));
        if (count <= kSah.max_leaf_size && float(count) * cluster_cost <= split_cost) return false;
        const float lo = centroids.lo[best_axis], sc = scale[best_axis];
        auto* pivot = std::partition(items.data() + begin, items.data() + end, [&](const Item& it) {
            return bin_of(it.centroid[best_axis] - lo, sc) <= best_plane;
        });
        const uint32_t mid = uint32_t(pivot - items.data());
        *left = Range{begin, mid, Box(), Box()};
        *right = Range{mid, end, Box(), Box()};
        for (int b = 0; b < kBins; ++b) {
            const Bin& bin = bins[best_axis][b];
            Range& side = b <= best_plane ? *left : *right;
            side.bounds.grow(bin.box);
            side.centroids.grow(bin.centroids);
        }
        return true;
    }
    // All centroids coincide (or are not finite): object median by input order.
    if (count <= kSah.max_leaf_size) return false;
    const uint32_t mid = begin + count / 2;
    *left = Range{begin, mid, Box(), Box()};
    *right = Range{mid, end, Box(), Box()};
    for (uint32_t i = begin; i < end; ++i) {
        Range& side = i < mid ? *left : *right;
        side.bounds.grow(items[i].box);
        side.centroids.grow_point(items[i].centroid);
    }
    return true;
}

struct ClusterSplitter {
    std::vector<Item>& items;
    bool split(const Range& range, int /*depth*/, Range* left, Range* right) const {
        return split_node(items, range, left, right);
    }
};

// The node emitter: BottomLevelNode, an inner node naming its left child (the right one
// follows it).
struct BottomLevelNodeEmitter {
    using Node = BottomLevelNode;
    static void set_box(Node& node, const Box& b) {
        for (int a = 0; a < 3; ++a) {
            node.bounds_min[a] = b.lo[a];
            node.bounds_max[a] = b.hi[a];
        }
    }
    void leaf(Node& node, const Range& r) const {
        set_box(node, r.bounds);
        node.first = r.begin;
        node.count = r.count();
    }
    void inner(Node& node, const Range& r) const {
        set_box(node, r.bounds);
        node.count = 0;
    }
    void link(Node& node, uint32_t left_child) const { node.first = left_child; }
    uint32_t linked(const Node& node) const { return node.first; }
    bool is_inner(const Node& node) const { return node.count == 0; }
};

// Subtrees of more than this many items build their two halves in parallel.
constexpr uint32_t kSequentialSubtree = 4096;

}  // namespace

uint64_t bottom_level_size_bound(uint64_t cluster_count) {
    uint64_t nodes = cluster_count == 0 ? 0 : 2 * cluster_count - 1;
    return sizeof(BottomLevelHeader) + nodes * sizeof(BottomLevelNode) +
           cluster_count * sizeof(ClusterReference);
}

std::vector<std::byte> build_bottom_level(std::span<const ClusterBox> clusters,
                                          uint32_t input_reference_count) {
    std::vector<Item> items;
    items.reserve(clusters.size());
    for (uint32_t i = 0; i < clusters.size(); ++i) {
        const ClusterBox& c = clusters[i];
        if (!valid_box(c)) continue;
        Item it;
        for (int a = 0; a < 3; ++a) {
            it.box.lo[a] = c.bounds_min[a];
            it.box.hi[a] = c.bounds_max[a];
            // Clamp so that huge-but-finite boxes still give finite centroids.
            double mid = 0.5 * (double(c.bounds_min[a]) + double(c.bounds_max[a]));
            it.centroid[a] = float(std::clamp(mid, -double(std::numeric_limits<float>::max()),
                                              double(std::numeric_limits<float>::max())));
        }
        it.source = i;
        items.push_back(it);
    }
    const uint64_t n = items.size();
    if (bottom_level_size_bound(n) > std::numeric_limits<uint32_t>::max()) return {};

    std::vector<BottomLevelNode> nodes;
    if (n > 0) {
        Box bounds, centroids;
        for (const Item& it : items) {
            bounds.grow(it.box);
            centroids.grow_point(it.centroid);
        }
        const ClusterSplitter splitter{items};
        geometry::TopDownBuilder<geometry::NodeLayout::kSiblingPairs, Range, ClusterSplitter,
                                 BottomLevelNodeEmitter>(splitter, BottomLevelNodeEmitter{},
                                                         kSequentialSubtree + 1)
            .append(nodes, Range{0, uint32_t(n), bounds, centroids}, 0);
    }

    BottomLevelHeader h{};
    h.magic = kObjectMagic;
    h.object_type = uint8_t(ObjectType::kClustersBottomLevel);
    h.format_version = kBottomLevelFormatVersion;
    h.reference_count = uint32_t(n);
    h.node_count = uint32_t(nodes.size());
    h.nodes_offset = sizeof(BottomLevelHeader);
    h.references_offset = uint32_t(h.nodes_offset + nodes.size() * sizeof(BottomLevelNode));
    h.object_size = uint32_t(h.references_offset + n * sizeof(ClusterReference));
    h.input_reference_count = input_reference_count;
    if (n > 0) {
        std::memcpy(h.bounds_min, nodes[0].bounds_min, sizeof h.bounds_min);
        std::memcpy(h.bounds_max, nodes[0].bounds_max, sizeof h.bounds_max);
    } else {
        // Empty box, as the CLAS format writes one for an empty cluster.
        for (int a = 0; a < 3; ++a) {
            h.bounds_min[a] = std::numeric_limits<float>::infinity();
            h.bounds_max[a] = -std::numeric_limits<float>::infinity();
        }
    }
    std::vector<std::byte> out(h.object_size);
    std::memcpy(out.data(), &h, sizeof h);
    if (!nodes.empty())
        std::memcpy(out.data() + h.nodes_offset, nodes.data(),
                    nodes.size() * sizeof(BottomLevelNode));
    for (uint64_t i = 0; i < n; ++i) {
        const ClusterBox& c = clusters[items[i].source];
        ClusterReference r{c.clas_address, c.reference_index, c.cluster_id};
        std::memcpy(out.data() + h.references_offset + i * sizeof r, &r, sizeof r);
    }
    return out;
}

BottomLevelCheck read_bottom_level_header(std::span<const std::byte> bytes) {
    BottomLevelCheck r;
    if (bytes.size() < sizeof(BottomLevelHeader)) {
        r.error = "shorter than a bottom-level header (" + std::to_string(bytes.size()) + " bytes)";
        return r;
    }
    BottomLevelHeader h;
    std::memcpy(&h, bytes.data(), sizeof h);
    if (h.magic != kObjectMagic) {
        r.error = "no engine object magic";
        return r;
    }
    if (h.object_type != uint8_t(ObjectType::kClustersBottomLevel)) {
        r.error = "object type " + std::to_string(h.object_type) +
                  " is not a clusters bottom-level structure";
        return r;
    }
    if (h.format_version != kBottomLevelFormatVersion) {
        r.error = "unknown bottom-level format version " + std::to_string(h.format_version);
        return r;
    }
    uint64_t nodes_end =
        uint64_t(h.nodes_offset) + uint64_t(h.node_count) * sizeof(BottomLevelNode);
    uint64_t refs_end =
        uint64_t(h.references_offset) + uint64_t(h.reference_count) * sizeof(ClusterReference);
    if (h.object_size > bytes.size() || h.nodes_offset < sizeof h ||
        h.references_offset < sizeof h || nodes_end > h.object_size || refs_end > h.object_size) {
        r.error = "sections run past object_size " + std::to_string(h.object_size);
        return r;
    }
    if ((h.reference_count == 0) != (h.node_count == 0) ||
        h.node_count > 2ull * h.reference_count) {
        r.error = "node count " + std::to_string(h.node_count) + " does not fit reference count " +
                  std::to_string(h.reference_count);
        return r;
    }
    for (uint32_t i = 0; i < h.node_count; ++i) {
        BottomLevelNode node;
        std::memcpy(&node, bytes.data() + h.nodes_offset + uint64_t(i) * sizeof node, sizeof node);
        bool ok = node.count == 0 ? (node.first > i && uint64_t(node.first) + 1 < h.node_count)
                                  : (node.count <= kBottomLevelMaxLeafSize &&
                                     uint64_t(node.first) + node.count <= h.reference_count);
        if (!ok) {
            r.error = "node " + std::to_string(i) + " points outside the object";
            return r;
        }
    }
    r.header = h;
    return r;
}

}  // namespace clastrace::engine
