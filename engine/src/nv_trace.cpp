// SPDX-License-Identifier: Apache-2.0
// Traversal of NV objects (nv_trace.h): the engine's conservative slab test over the
// trees and its watertight triangle test (geometry/), Vulkan's instance and ray flag rules.
#include "clastrace/engine/nv_trace.h"

#include "clastrace/common/hex.h"
#include "clastrace/engine/blas.h"

#include "nv_wide_tree.h"
#include "spill_stack.h"

#include "geometry/float32.h"
#include "geometry/slab.h"
#include "geometry/triangle.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <unordered_map>

namespace clastrace::engine {
namespace {

using common::hex;

struct Blas {
    std::vector<std::byte> bytes;
    NvObjectView view;
    std::vector<NvPrimitiveRecord> primitives;
    std::vector<NvNode> nodes;
    detail::WideTree wide;  // `nodes` in the traversal's layout
    // Triangles: the wide leaves' records in groups of four (`wide` indexes these).
    detail::HugePageVector<geometry::Triangle4> groups;
    std::vector<uint32_t> geometry_flags;
    bool aabbs = false;
    // A cluster BLAS (blas.h): `bytes` is that object, `clas` the CLAS its references name
    // (address -> bytes; a reference whose address holds no CLAS is absent and never hit).
    bool clusters = false;
    std::unordered_map<uint64_t, std::vector<std::byte>> clas;
    // Each of them opened once (the map's nodes and the vectors' bytes stay where they are
    // when the Blas moves).
    std::unordered_map<uint64_t, ClasView> clas_views;
};

// The rules of nv_trace.h a candidate must pass that depend only on the instance's and the
// ray's flags, decided once per instance entry rather than at every primitive.
struct HitRules {
    int opacity = -1;             // 1 / 0: forced opaque / not opaque; -1: the geometry's flag
    unsigned culled_opacity = 0;  // bit 1: opaque candidates culled, bit 0: non-opaque ones
    bool flip = false;            // TRIANGLE_FRONT_COUNTERCLOCKWISE
    bool cull_front = false, cull_back = false;  // after TRIANGLE_CULL_DISABLE
};

HitRules hit_rules(uint32_t instance_flags, uint32_t flags) {
    HitRules h;
    // Opacity: geometry flag < instance force flags < ray flags.
    if (instance_flags & VK_GEOMETRY_INSTANCE_FORCE_OPAQUE_BIT_NV) h.opacity = 1;
    if (instance_flags & VK_GEOMETRY_INSTANCE_FORCE_NO_OPAQUE_BIT_NV) h.opacity = 0;
    if (flags & kRayFlagOpaque) h.opacity = 1;
    if (flags & kRayFlagNoOpaque) h.opacity = 0;
    h.culled_opacity =
        (flags & kRayFlagCullOpaque ? 2u : 0u) | (flags & kRayFlagCullNoOpaque ? 1u : 0u);
    h.flip = instance_flags & VK_GEOMETRY_INSTANCE_TRIANGLE_FRONT_COUNTERCLOCKWISE_BIT_NV;
    if (!(instance_flags & VK_GEOMETRY_INSTANCE_TRIANGLE_CULL_DISABLE_BIT_NV)) {
        h.cull_back = flags & kRayFlagCullBackFacingTriangles;
        h.cull_front = flags & kRayFlagCullFrontFacingTriangles;
    }
    return h;
}

struct Instance {
    const Blas* blas = nullptr;  // nullptr: never visited
    double inverse[12];
    // The world-to-object matrix a float32 pipeline holds: `inverse` rounded to float, i.e.
    // the driver inverts the 3x4 matrix exactly (or closely enough) and stores floats.
    float inverse_float[12];
    bool identity = false;  // `inverse` is exactly the identity (to_object_space)
    uint32_t mask = 0;
    uint32_t custom_index = 0;
    uint32_t sbt_offset = 0;
    uint32_t flags = 0;
    // hit_rules(flags, 0): a ray without flags (the common one) takes them from here.
    HitRules rules_without_ray_flags;
};

// Entry distance of the ray into the box within [r.tmin, tmax], or NaN for a miss.
double box_entry(const geometry::PreparedRay& r, const float lo[3], const float hi[3],
                 double tmax) {
    double entry;
    return geometry::slab_test<true>(r, lo, hi, tmax, &entry)
               ? entry
               : std::numeric_limits<double>::quiet_NaN();
}

bool is_identity(const double m[12]) {
    for (int k = 0; k < 12; ++k)
        if (m[k] != (k % 5 == 0 ? 1.0 : 0.0)) return false;
    return true;
}

bool invert(const float m[12], double out[12]) {
    const double a = m[0], b = m[1], c = m[2], d = m[4], e = m[5], f = m[6], g = m[8], h = m[9],
                 i = m[10];
    const double det = a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g);
    if (det == 0.0 || !std::isfinite(det)) return false;
    const double s = 1.0 / det;
    const double r[9] = {(e * i - f * h) * s, (c * h - b * i) * s, (b * f - c * e) * s,
                         (f * g - d * i) * s, (a * i - c * g) * s, (c * d - a * f) * s,
                         (d * h - e * g) * s, (b * g - a * h) * s, (a * e - b * d) * s};
    const double t[3] = {m[3], m[7], m[11]};
    for (int row = 0; row < 3; ++row) {
        out[4 * row] = r[3 * row];
        out[4 * row + 1] = r[3 * row + 1];
        out[4 * row + 2] = r[3 * row + 2];
        out[4 * row + 3] = -(r[3 * row] * t[0] + r[3 * row + 1] * t[1] + r[3 * row + 2] * t[2]);
    }
    return true;
}

// A cluster BLAS an instance names, copied with the CLAS it references; each reference
// whose address holds no CLAS now is one finding (the same rule the cluster traversal uses).
std::optional<Blas> load_cluster_blas(const MemoryImage& memory, uint64_t address,
                                      std::vector<Finding>* findings, std::string* error) {
    ObjectDirectory bytes_only;  // judged by the bytes, as for objects of a first snapshot
    const FieldRef where{"bottom-level object", -1};
    ObjectLookup found =
        bytes_only.lookup(memory, address, ObjectType::kClustersBottomLevel, false, where);
    if (!found.found()) {
        if (error) *error = found.error;
        return std::nullopt;
    }
    BottomLevelCheck check = read_bottom_level_header(found.bytes);
    if (!check.header) {
        if (error) *error = "a cluster BLAS that does not check out: " + check.error;
        return std::nullopt;
    }
    Blas b;
    b.clusters = true;
    b.bytes.assign(found.bytes.begin(), found.bytes.end());
    for (uint32_t k = 0; k < check.header->reference_count; ++k) {
        ClusterReference ref;
        std::memcpy(&ref,
                    b.bytes.data() + check.header->references_offset + uint64_t(k) * sizeof ref,
                    sizeof ref);
        if (b.clas.count(ref.clas_address)) continue;
        ObjectLookup clas =
            bytes_only.lookup(memory, ref.clas_address, ObjectType::kTriangleCluster, false, where);
        if (clas.found() && open_clas(clas.bytes)) {
            const auto& kept =
                b.clas
                    .emplace(ref.clas_address,
                             std::vector<std::byte>(clas.bytes.begin(), clas.bytes.end()))
                    .first->second;
            b.clas_views.emplace(ref.clas_address, *open_clas(kept));
        } else if (findings) {
            findings->push_back(Finding{kRuleStaleClusterReference,
                                        "cluster BLAS " + hex(address) + ", cluster reference " +
                                            std::to_string(ref.reference_index) + ": " +
                                            (clas.found() ? "not a checked CLAS" : clas.error),
                                        -1, ref.clas_address});
        }
    }
    return b;
}

std::optional<Blas> load_blas(const MemoryImage& memory, uint64_t address,
                              std::vector<Finding>* findings, std::string* error) {
    try {
        uint32_t magic = 0;
        std::memcpy(&magic,
                    memory.read_bytes(address, 4, FieldRef{"bottom-level object", -1}).data(), 4);
        if (magic == kObjectMagic) return load_cluster_blas(memory, address, findings, error);
        auto head =
            memory.read_bytes(address, sizeof(NvObjectHeader), FieldRef{"bottom-level object", -1});
        auto h = read_nv_header(head, error);
        if (!h) return std::nullopt;
        if (h->kind != uint8_t(NvObjectKind::kBottomLevel)) {
            if (error) *error = "a top-level object where a bottom-level one was expected";
            return std::nullopt;
        }
        auto bytes =
            memory.read_bytes(address, h->object_size, FieldRef{"bottom-level object", -1});
        Blas b;
        b.bytes.assign(bytes.begin(), bytes.end());
        auto view = open_nv_object(b.bytes, error);
        if (!view) return std::nullopt;
        b.view = *view;
        b.aabbs = h->geometry_type == VK_GEOMETRY_TYPE_AABBS_NV;
        b.primitives.resize(h->primitive_count);
        for (uint32_t i = 0; i < h->primitive_count; ++i) b.primitives[i] = view->primitive(i);
        b.nodes.resize(h->node_count);
        for (uint32_t i = 0; i < h->node_count; ++i) b.nodes[i] = view->node(i);
        b.wide = detail::make_wide_tree(b.nodes);
        if (!b.aabbs) b.groups = detail::group_leaf_triangles(&b.wide, b.primitives);
        b.geometry_flags.resize(h->geometry_count);
        for (uint32_t g = 0; g < h->geometry_count; ++g)
            b.geometry_flags[g] = view->geometry(g).geometry_flags;
        return b;
    } catch (const MemoryFault& f) {
        if (error) *error = f.message;
        return std::nullopt;
    }
}

}  // namespace

struct NvScene::Data {
    std::vector<NvNode> nodes;  // top-level tree; empty for a single-BLAS scene
    detail::WideTree wide;      // `nodes` in the traversal's layout
    std::vector<Instance> instances;
    std::unordered_map<uint64_t, std::unique_ptr<Blas>> blas;
    uint32_t reached = 0;
    // open_bottom's scene: one identity instance under a root of infinite bounds, which every
    // finite ray enters, so those skip the top level's walk.
    bool single_bottom = false;
};

std::optional<NvScene> NvScene::open(const MemoryImage& memory, uint64_t address,
                                     std::vector<Finding>* findings, std::string* error) {
    std::vector<std::byte> bytes;
    std::optional<NvObjectView> view;
    try {
        auto head =
            memory.read_bytes(address, sizeof(NvObjectHeader), FieldRef{"top-level object", -1});
        auto h = read_nv_header(head, error);
        if (!h) return std::nullopt;
        if (h->kind != uint8_t(NvObjectKind::kTopLevel)) {
            if (error) *error = "a bottom-level object where a top-level one was expected";
            return std::nullopt;
        }
        auto span = memory.read_bytes(address, h->object_size, FieldRef{"top-level object", -1});
        bytes.assign(span.begin(), span.end());
    } catch (const MemoryFault& f) {
        if (error) *error = f.message;
        return std::nullopt;
    }
    view = open_nv_object(bytes, error);
    if (!view) return std::nullopt;
    auto data = std::make_shared<Data>();
    data->nodes.resize(view->header.node_count);
    for (uint32_t i = 0; i < view->header.node_count; ++i) data->nodes[i] = view->node(i);
    data->wide = detail::make_wide_tree(data->nodes);
    data->instances.resize(view->header.primitive_count);
    for (uint32_t i = 0; i < view->header.primitive_count; ++i) {
        const NvInstanceRecord r = view->instance(i);
        Instance& inst = data->instances[i];
        inst.mask = r.custom_index_and_mask >> 24;
        inst.custom_index = r.custom_index_and_mask & 0xFFFFFFu;
        inst.sbt_offset = r.sbt_offset_and_flags & 0xFFFFFFu;
        inst.flags = r.sbt_offset_and_flags >> 24;
        inst.rules_without_ray_flags = hit_rules(inst.flags, 0);
        if (!r.active || r.blas_address == 0 || !invert(r.transform, inst.inverse)) continue;
        for (int k = 0; k < 12; ++k) inst.inverse_float[k] = float(inst.inverse[k]);
        inst.identity = is_identity(inst.inverse);
        auto it = data->blas.find(r.blas_address);
        if (it == data->blas.end()) {
            std::string why;
            std::optional<Blas> b = load_blas(memory, r.blas_address, findings, &why);
            if (!b && findings)
                findings->push_back(
                    Finding{kRuleNvStaleInstance,
                            "instance " + std::to_string(i) +
                                ": the bottom-level object it was built with is gone: " + why,
                            -1, r.blas_address});
            it = data->blas
                     .emplace(r.blas_address, b ? std::make_unique<Blas>(std::move(*b)) : nullptr)
                     .first;
        }
        inst.blas = it->second.get();
        data->reached += inst.blas != nullptr;
    }
    return NvScene(std::move(data));
}

std::optional<NvScene> NvScene::open_bottom(const MemoryImage& memory, uint64_t address,
                                            std::string* error) {
    std::optional<Blas> b = load_blas(memory, address, nullptr, error);
    if (!b) return std::nullopt;
    auto data = std::make_shared<Data>();
    Instance inst;
    const double identity[12] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0};
    std::memcpy(inst.inverse, identity, sizeof identity);
    for (int k = 0; k < 12; ++k) inst.inverse_float[k] = float(identity[k]);
    inst.identity = true;
    inst.mask = 0xFF;
    inst.rules_without_ray_flags = hit_rules(inst.flags, 0);
    auto& slot = data->blas[address];
    slot = std::make_unique<Blas>(std::move(*b));
    inst.blas = slot.get();
    data->instances.push_back(inst);
    NvNode root{};
    root.bounds_min[0] = root.bounds_min[1] = root.bounds_min[2] =
        -std::numeric_limits<float>::infinity();
    root.bounds_max[0] = root.bounds_max[1] = root.bounds_max[2] =
        std::numeric_limits<float>::infinity();
    root.first = 0;
    root.count = 1;
    data->nodes.push_back(root);
    data->wide = detail::make_wide_tree(data->nodes);
    data->reached = 1;
    data->single_bottom = true;
    return NvScene(std::move(data));
}

uint32_t NvScene::instance_count() const { return uint32_t(data_->instances.size()); }
uint32_t NvScene::instances_reached() const { return data_->reached; }

uint64_t NvScene::traversal_bytes(uint64_t* wide_nodes) const {
    uint64_t bytes = data_->nodes.size() * sizeof(NvNode) + data_->wide.bytes();
    uint64_t wide = data_->wide.node_count();
    for (const auto& [address, b] : data_->blas) {
        if (!b || b->clusters) continue;
        bytes += b->primitives.size() * sizeof(NvPrimitiveRecord) +
                 b->nodes.size() * sizeof(NvNode) + b->wide.bytes() +
                 b->groups.size() * sizeof(geometry::Triangle4);
        wide += b->wide.node_count();
    }
    if (wide_nodes) *wide_nodes = wide;
    return bytes;
}

namespace {

// Visits the leaves of one tree (top or bottom level) that the ray's [tmin, *tmax] reaches,
// near child first, each stack entry with the distance at which the ray enters its box so
// closest-hit queries skip subtrees behind the best hit so far (`leaf` lowers *tmax). A fixed
// stack covers every tree the builder makes; deeper (hostile but checked) trees spill into the
// vector. `leaf` returns true to stop (first-hit queries).
// Boxes are culled against the best t widened by 2^-20 of itself: a box entered at that same
// t (the best hit lies on a vertex or edge on its face) rounds its entry either way, and its
// tied hit must still be seen for ties to resolve by key (replaces), not by visiting order.
// Out of line: inlined, its stack made the frame of every traversal that might take it.
template <class Leaf>
[[gnu::noinline]] void walk_tree(const std::vector<NvNode>& nodes, const geometry::PreparedRay& rd,
                                 double* tmax, Leaf&& leaf) {
    auto reach = [tmax] { return *tmax + std::fabs(*tmax) * 0x1p-20; };
    struct Entry {
        uint32_t node;
        double t;
    };
    Entry entries[192];
    std::vector<Entry> overflow;
    SpillStack<Entry, 192> stack(entries, &overflow);
    auto push = [&](uint32_t node, double t) { stack.push(Entry{node, t}); };
    {
        const double t0 = box_entry(rd, nodes[0].bounds_min, nodes[0].bounds_max, reach());
        if (!std::isnan(t0)) push(0, t0);
    }
    while (!stack.empty()) {
        const Entry e = stack.pop();
        if (e.t > reach()) continue;
        const uint32_t ni = e.node;
        const NvNode& n = nodes[ni];
        if (n.count == 0) {
            const NvNode &l = nodes[ni + 1], &r = nodes[n.first];
            const double tl = box_entry(rd, l.bounds_min, l.bounds_max, reach());
            const double tr = box_entry(rd, r.bounds_min, r.bounds_max, reach());
            const bool hl = !std::isnan(tl), hr = !std::isnan(tr);
            if (hl && hr) {
                if (tl <= tr) {
                    push(n.first, tr);
                    push(ni + 1, tl);
                } else {
                    push(ni + 1, tl);
                    push(n.first, tr);
                }
            } else if (hl) {
                push(ni + 1, tl);
            } else if (hr) {
                push(n.first, tr);
            }
            continue;
        }
        if (leaf(n)) return;
    }
}

// Visits the leaves through the 4-wide layout (`wide_leaf(first, count)`: `first` indexes
// `wide_items`, the records or, for a tree with leaf_groups, their groups of four; `count` is
// the records), or through the stored binary tree (`leaf(first, count)`, records, as
// walk_tree's) for the rays the SIMD box test cannot bound or whose origin is too far for
// float distances to tell the leaves apart (nv_wide_tree.h). Both keep every box the ray
// meets; only the order of the leaves differs. A leaf's items are fetched ahead. `wr` is
// make_wide_ray of `rd`.
template <class WideItems, class Leaf, class WideLeaf>
void walk_leaves(const std::vector<NvNode>& nodes, const detail::WideTree& wide,
                 const WideItems& wide_items, const geometry::PreparedRay& rd,
                 const detail::WideRay& wr, double* tmax, Leaf&& leaf, WideLeaf&& wide_leaf) {
    // A float32 ray's box test is as wide as the scalar float32 one (make_wide_ray): from far
    // away the 4-wide walk is still the faster of the two.
    if (wr.usable && (rd.mode == TraversalMode::kFloat32 || detail::resolves_leaves(wide, rd.o))) {
        detail::walk_wide(wide, wr, tmax, wide_leaf, [&](uint32_t first, uint32_t count) {
            // Items of whole cache lines (groups of four triangles) line by line, unrolled:
            // a leaf is mostly one group.
            using WideItem = typename WideItems::value_type;
            constexpr size_t kLines = sizeof(WideItem) % 64 == 0 ? sizeof(WideItem) / 64 : 0;
            if constexpr (kLines != 0) {
                const uint32_t items = wide.leaf_groups ? (count + 3) / 4 : count;
                for (const WideItem* item = wide_items.data() + first;
                     item != wide_items.data() + first + items; ++item) {
                    const char* line = reinterpret_cast<const char*>(item);
#pragma GCC unroll 4
                    for (size_t k = 0; k < kLines; ++k) __builtin_prefetch(line + 64 * k);
                }
            } else {
                const uint32_t items = wide.leaf_groups ? (count + 3) / 4 : count;
                const char* from = reinterpret_cast<const char*>(wide_items.data() + first);
                const char* to = reinterpret_cast<const char*>(wide_items.data() + first + items);
                for (const char* line = from; line < to; line += 64) __builtin_prefetch(line);
            }
        });
        return;
    }
    walk_tree(nodes, rd, tmax, [&](const NvNode& n) { return leaf(n.first, n.count); });
}

// Whether a hit at `t` replaces the closest so far (at *tmax): nearer, or as near and with a
// lower (instance, geometry, primitive) key, so that ties do not depend on the visiting order.
bool replaces(const NvHit& best, double t, double tmax, uint32_t instance, uint32_t geometry,
              uint32_t primitive) {
    if (!best.hit || t < tmax) return true;
    if (!(t == tmax)) return false;
    if (instance != best.instance_index) return instance < best.instance_index;
    if (geometry != best.geometry_index) return geometry < best.geometry_index;
    return primitive < best.primitive_index;
}

// The largest magnitude among a primitive's coordinates: a box's six bounds, a triangle's nine.
float largest_coordinate(const float* v, bool aabb) {
    float largest = 0.0f;
#pragma GCC unroll 6
    for (int i = 0; i < 6; ++i) largest = std::max(largest, std::fabs(v[i]));
    if (!aabb) largest = std::max({largest, std::fabs(v[6]), std::fabs(v[7]), std::fabs(v[8])});
    return largest;
}

// The float32 error bound of NvHit::t_error: 8 ulps of the largest magnitude that enters
// the driver's arithmetic (object-space primitive coordinates, `largest` of them, and origin,
// and the terms of the world-to-object transform), over the largest direction component, plus
// 8 ulps of t. (Loops unrolled: a closest hit computes this once or more per ray.) `o_is_wo`:
// `o` is the world origin itself (an identity's plain ray, make_plain_object_rays), whose
// transform terms, |wo[r]| each, are then among |o[a]| already.
double float_t_error(const Instance& inst, const float wo[3], const double o[3], const double d[3],
                     float largest, double t, bool o_is_wo) {
    double scale = 0.0;
#pragma GCC unroll 3
    for (int a = 0; a < 3; ++a) scale = std::max(scale, std::fabs(o[a]));
    scale = std::max(scale, double(largest));
#pragma GCC unroll 3
    for (int r = 0; r < 3 && !o_is_wo; ++r) {
        const double* m = inst.inverse + 4 * r;
        scale = std::max(scale, std::fabs(m[0] * wo[0]) + std::fabs(m[1] * wo[1]) +
                                    std::fabs(m[2] * wo[2]) + std::fabs(m[3]));
    }
    const double dmax = std::max({std::fabs(d[0]), std::fabs(d[1]), std::fabs(d[2])});
    const double ulp = std::numeric_limits<float>::epsilon();
    return 8.0 * ulp * (dmax > 0.0 ? scale / dmax : 0.0) + 8.0 * ulp * std::fabs(t);
}

// The world ray in the instance's object space. kDouble: through the double inverse.
// kFloat32: through the float world-to-object matrix, each row evaluated in float as
// ((m0 x + m1 y) + m2 z) + m3 without fused multiply-adds (the results are floats).
void to_object_space(const Instance& inst, const Ray& ray, TraversalMode mode, double o[3],
                     double d[3]) {
    // Through an identity, a finite ray with no zero direction component comes out as itself
    // in either mode: each row's products are exact and its sums add zeros to the one nonzero
    // term (an origin component -0 becomes +0 through the row's final + 0). Zero and non-finite
    // components (0 x inf is NaN; zeros' signs) take the rows below.
    if (inst.identity) {
        bool plain = true;
        for (int a = 0; a < 3; ++a)
            plain &= std::isfinite(ray.origin[a]) & std::isfinite(ray.direction[a]) &
                     (ray.direction[a] != 0.0f);
        if (plain) {
            for (int a = 0; a < 3; ++a) {
                o[a] = double(ray.origin[a]) + 0.0;
                d[a] = ray.direction[a];
            }
            return;
        }
    }
    for (int r = 0; r < 3; ++r) {
        if (mode == TraversalMode::kFloat32) {
            const float* m = inst.inverse_float + 4 * r;
            const float* wo = ray.origin;
            const float* wd = ray.direction;
            o[r] = ((m[0] * wo[0] + m[1] * wo[1]) + m[2] * wo[2]) + m[3];
            d[r] = (m[0] * wd[0] + m[1] * wd[1]) + m[2] * wd[2];
        } else {
            const double* m = inst.inverse + 4 * r;
            o[r] = m[0] * double(ray.origin[0]) + m[1] * double(ray.origin[1]) +
                   m[2] * double(ray.origin[2]) + m[3];
            d[r] = m[0] * double(ray.direction[0]) + m[1] * double(ray.direction[1]) +
                   m[2] * double(ray.direction[2]);
        }
    }
}

// Where the engine, standing in for the ray check's intersection shader, reports an AABB
// primitive's hit: kDouble the conservative slab entry; kFloat32 the shader's own float slab
// test (geometry/float32.h). NaN for none within [tmin, tmax].
double aabb_primitive_entry(const geometry::PreparedRay& r, const float lo[3], const float hi[3],
                            double tmax) {
    if (r.mode != TraversalMode::kFloat32) return box_entry(r, lo, hi, tmax);
    double t;
    if (!geometry::aabb_shader_float32(r, lo, hi, &t) || t > tmax)
        return std::numeric_limits<double>::quiet_NaN();
    return t;
}

// The ray flags a cluster BLAS's traversal applies for this instance: its flags put into the
// ray's terms (FORCE_(NO_)OPAQUE unless the ray forces opacity itself, CULL_DISABLE drops the
// facing culls, FRONT_COUNTERCLOCKWISE swaps them), as the NV traversal applies them per
// primitive.
uint32_t cluster_ray_flags(uint32_t flags, uint32_t instance_flags) {
    if (!(flags & (kRayFlagOpaque | kRayFlagNoOpaque))) {
        if (instance_flags & VK_GEOMETRY_INSTANCE_FORCE_OPAQUE_BIT_NV) flags |= kRayFlagOpaque;
        if (instance_flags & VK_GEOMETRY_INSTANCE_FORCE_NO_OPAQUE_BIT_NV) flags |= kRayFlagNoOpaque;
    }
    const uint32_t facing = kRayFlagCullBackFacingTriangles | kRayFlagCullFrontFacingTriangles;
    if (instance_flags & VK_GEOMETRY_INSTANCE_TRIANGLE_CULL_DISABLE_BIT_NV) {
        flags &= ~facing;
    } else if (instance_flags & VK_GEOMETRY_INSTANCE_TRIANGLE_FRONT_COUNTERCLOCKWISE_BIT_NV) {
        const uint32_t back = flags & kRayFlagCullBackFacingTriangles,
                       front = flags & kRayFlagCullFrontFacingTriangles;
        flags = (flags & ~facing) | (back ? uint32_t(kRayFlagCullFrontFacingTriangles) : 0u) |
                (front ? uint32_t(kRayFlagCullBackFacingTriangles) : 0u);
    }
    return flags;
}

// An instance of a cluster BLAS: the ray in object space through the cluster traversal
// (blas.h), its hit reported in the NV terms (primitive = the triangle's input index).
bool trace_cluster_instance(const Instance& inst, uint32_t index, const double o[3],
                            const double d[3], uint32_t flags, bool first_hit, double tmin,
                            double* tmax, NvHit* best, TraversalMode mode) {
    const Blas& b = *inst.blas;
    const Ray object_ray{{float(o[0]), float(o[1]), float(o[2])},
                         float(tmin),
                         {float(d[0]), float(d[1]), float(d[2])},
                         float(*tmax)};
    auto clas_at = [&b](uint64_t address) -> const ClasView* {
        auto it = b.clas_views.find(address);
        return it == b.clas_views.end() ? nullptr : &it->second;
    };
    const BottomLevelHit h =
        trace_bottom_level_views(b.bytes, clas_at, object_ray, cluster_ray_flags(flags, inst.flags),
                                 first_hit, mode);
    if (!h.hit.hit || double(h.hit.t) < tmin) return false;
    // Strictly before *tmax, or a tie with a previous instance's hit that the key settles.
    if (!(double(h.hit.t) < *tmax) &&
        !(best && best->hit &&
          replaces(*best, h.hit.t, *tmax, index, h.hit.geometry_index, h.hit.triangle_index)))
        return false;
    const bool flip = inst.flags & VK_GEOMETRY_INSTANCE_TRIANGLE_FRONT_COUNTERCLOCKWISE_BIT_NV;
    if (best) {
        best->hit = true;
        best->t = h.hit.t;
        best->instance_index = index;
        best->instance_custom_index = inst.custom_index;
        best->sbt_offset = inst.sbt_offset;
        best->geometry_index = h.hit.geometry_index;
        best->primitive_index = h.hit.triangle_index;
        best->cluster_id = h.hit.cluster_id;
        best->u = h.hit.u;
        best->v = h.hit.v;
        best->uv_error = h.hit.uv_error;
        best->hit_kind = h.hit.front_face != flip ? kHitKindFrontFacing : kHitKindBackFacing;
        best->opaque = h.hit.opaque;
        // The object-space ray was rounded to float once more: a few ulps of t.
        best->t_error = 16.0f * std::numeric_limits<float>::epsilon() * std::fabs(h.hit.t);
    }
    *tmax = h.hit.t;
    return true;
}

// One traversal of one instance's NV BLAS: its state in one object, so that the leaf
// functions the walks call capture one pointer (closures of many references cost about 40
// instructions a ray to build, and registers inside the walks).
class InstanceTrace {
public:
    // `plain`: `rays` are make_plain_object_rays' (an identity instance).
    InstanceTrace(const Instance& inst, uint32_t index, const float* world_origin, uint32_t flags,
                  bool first_hit, double* tmax, NvHit* best, const detail::ObjectRays& rays,
                  bool plain)
        : inst_(inst),
          b_(*inst.blas),
          index_(index),
          world_origin_(world_origin),
          first_hit_(first_hit),
          tmax_(tmax),
          tmax_up_(detail::float_at_or_above(*tmax)),
          best_(best),
          rays_(rays),
          rules_(flags == 0 ? inst.rules_without_ray_flags : hit_rules(inst.flags, flags)),
          plain_(plain) {}

    bool found() const { return found_; }

    // Primitives [first, first + count) of the records in order; true: stop (first hit taken).
    bool records(uint32_t first, uint32_t count) {
        for (uint32_t k = first; k < first + count; ++k) {
            const NvPrimitiveRecord& p = b_.primitives[k];
            if (primitive(p.v, p.geometry_index, p.primitive_index)) return true;
        }
        return false;
    }

    // Triangles: each group's sure misses dropped four at a time, the rest in record order.
    // Always inlined, and the filter with it, into the SSE walk and into the AVX2 walk's leaf
    // function (wide8_leaf): there it compiles to the VEX form of the same SSE operations (no
    // fused multiply-adds: the same bits), where a call through a pointer to a copy per path
    // cost 2% more instructions.
    [[gnu::always_inline]] bool groups(uint32_t first, uint32_t count) {
        for (uint32_t g = 0; g < (count + 3) / 4; ++g) {
            const geometry::Triangle4& group = b_.groups[first + g];
            for (unsigned lanes =
                     geometry::triangle4_candidates(rays_.triangles, group,
                                                    geometry::group_lanes(g, count), tmax_up_);
                 lanes; lanes &= lanes - 1) {
                const int k = __builtin_ctz(lanes);
                // open_nv_object keeps leaves inside the records; a lane without one is skipped.
                if (group.geometry[k] == geometry::kNoTriangle) continue;
                float v[9];
                geometry::lane_vertices(group, k, v);
                if (primitive(v, group.geometry[k], group.primitive[k])) return true;
            }
        }
        return false;
    }

    // The float32 mode's leaves: each group's four triangles through the float32 test at once
    // (triangle4_float32), its hits taken in record order; the lanes it leaves to the scalar
    // test (an edge function 0 or not finite) through primitive(), in their place in that order.
    [[gnu::always_inline]] bool groups_float32(uint32_t first, uint32_t count) {
        for (uint32_t g = 0; g < (count + 3) / 4; ++g) {
            const geometry::Triangle4& group = b_.groups[first + g];
            geometry::Triangle4Float32 f;
            geometry::triangle4_float32(rays_.triangles, group, geometry::group_lanes(g, count),
                                        &f);
            for (unsigned lanes = f.hits | f.fallback; lanes; lanes &= lanes - 1) {
                const int k = __builtin_ctz(lanes);
                if (group.geometry[k] == geometry::kNoTriangle) continue;
                if ((f.fallback >> k) & 1u) {
                    float v[9];
                    geometry::lane_vertices(group, k, v);
                    if (primitive(v, group.geometry[k], group.primitive[k])) return true;
                } else if (float32_lane(group, k, f)) {
                    return true;
                }
            }
        }
        return false;
    }

    // One primitive (its coordinates `v`: a triangle's three vertices or a box's min and max)
    // through the exact tests and the flag rules; true: stop (first hit taken). Out of line:
    // under one call a ray, where inlined it took registers from the walks.
    [[gnu::noinline]] bool primitive(const float* v, uint32_t geometry_index,
                                     uint32_t primitive_index) {
        const bool opaque = is_opaque(geometry_index);
        if (opacity_culled(opaque)) return false;
        const geometry::PreparedRay& rd = rays_.exact;
        geometry::TriangleHit cand;
        uint32_t kind = 0;
        if (b_.aabbs) {
            const double t = aabb_primitive_entry(rd, v, v + 3, *tmax_);
            if (std::isnan(t)) return false;
            cand = geometry::TriangleHit{t, 0.0, 0.0, 0.0, true};
        } else {
            if (!geometry::intersect_triangle(rd, v, v + 3, v + 6, *tmax_, &cand)) return false;
            if (!facing_kind(cand.front, &kind)) return false;
        }
        const auto largest = [this, v] { return largest_coordinate(v, b_.aabbs); };
        return take(cand, kind, opaque, largest, geometry_index, primitive_index);
    }

    // Lane k of `group`, a hit of triangle4_float32: what intersect_triangle_float32 gives for
    // it, from the lanes, through primitive()'s rules. Out of line, as primitive() is.
    [[gnu::noinline]] bool float32_lane(const geometry::Triangle4& group, int k,
                                        const geometry::Triangle4Float32& f) {
        const uint32_t geometry_index = group.geometry[k];
        const bool opaque = is_opaque(geometry_index);
        if (opacity_culled(opaque)) return false;
        const double t = f.t[k];
        if (!(t >= rays_.exact.tmin && t <= *tmax_)) return false;
        const bool front = geometry::float_det_front(f.det[k]);
        uint32_t kind = 0;
        if (!facing_kind(front, &kind)) return false;
        const geometry::TriangleHit cand{t, f.u[k], f.v[k],
                                         geometry::barycentric_float_error(f.unsheared[k],
                                                                           f.sheared[k], f.det[k]),
                                         front};
        // The lane's coordinates read in place (a copy of the nine cost 18 instructions a hit).
        const auto largest = [&group, k] { return geometry::lane_largest_magnitude(group, k); };
        return take(cand, kind, opaque, largest, geometry_index, group.primitive[k]);
    }

private:
    bool is_opaque(uint32_t geometry_index) const {
        return rules_.opacity < 0
                   ? (b_.geometry_flags[geometry_index] & VK_GEOMETRY_OPAQUE_BIT_NV) != 0
                   : rules_.opacity != 0;
    }
    bool opacity_culled(bool opaque) const {
        return (rules_.culled_opacity >> unsigned(opaque)) & 1u;
    }

    // A triangle's hit kind from the test's facing after the instance's flip; false: culled.
    bool facing_kind(bool test_front, uint32_t* kind) const {
        const bool front = test_front != rules_.flip;
        if (front ? rules_.cull_front : rules_.cull_back) return false;
        *kind = front ? kHitKindFrontFacing : kHitKindBackFacing;
        return true;
    }

    // A candidate the exact test and the flag rules accept: kept when it replaces the best so
    // far (the tie rule), recorded, and *tmax_ lowered to it; true: stop (first hit taken).
    // `largest()`: the largest magnitude of its coordinates (float_t_error), for a recorded hit.
    template <class Largest>
    [[gnu::always_inline]] bool take(const geometry::TriangleHit& cand, uint32_t kind, bool opaque,
                                     const Largest& largest, uint32_t geometry_index,
                                     uint32_t primitive_index) {
        if (best_ && !replaces(*best_, cand.t, *tmax_, index_, geometry_index, primitive_index))
            return false;
        found_ = true;
        if (best_) {
            best_->hit = true;
            best_->t = float(cand.t);
            best_->instance_index = index_;
            best_->instance_custom_index = inst_.custom_index;
            best_->sbt_offset = inst_.sbt_offset;
            best_->geometry_index = geometry_index;
            best_->primitive_index = primitive_index;
            best_->u = float(cand.u);
            best_->v = float(cand.v);
            best_->uv_error = float(cand.uv_error);
            best_->hit_kind = kind;
            best_->opaque = opaque;
            best_->t_error = float(float_t_error(inst_, world_origin_, rays_.exact.o, rays_.exact.d,
                                                 largest(), cand.t, plain_));
        }
        *tmax_ = cand.t;
        tmax_up_ = detail::float_at_or_above(cand.t);
        return first_hit_;
    }

    const Instance& inst_;
    const Blas& b_;
    uint32_t index_;
    const float* world_origin_;
    bool first_hit_;
    double* tmax_;
    // *tmax_ rounded up to float, what the filter drops sure hits beyond (only primitive()
    // lowers *tmax_ while this traversal lasts).
    float tmax_up_;
    NvHit* best_;
    const detail::ObjectRays& rays_;
    HitRules rules_;
    bool plain_;
    bool found_ = false;
};

// One instance's BLAS: updates `best` (closest) or returns true at the first accepted
// hit (any / terminate-on-first-hit).
bool trace_instance(const Instance& inst, uint32_t index, const Ray& ray, uint32_t flags,
                    bool first_hit, double tmin, double* tmax, NvHit* best, TraversalMode mode,
                    bool exhaustive) {
    const Blas& b = *inst.blas;
    if (b.nodes.empty() && !b.clusters) return false;
    // The object-space ray's three forms: at once for a ray through an identity (every ray of
    // a bottom-level scene), in either mode, else by way of to_object_space.
    detail::ObjectRays rays;
    const bool plain =
        inst.identity && !b.clusters &&
        detail::make_plain_object_rays(ray.origin, ray.direction, tmin, *tmax, mode, &rays);
    if (!plain) {
        double o[3], d[3];
        to_object_space(inst, ray, mode, o, d);
        if (b.clusters)
            return trace_cluster_instance(inst, index, o, d, flags, first_hit, tmin, tmax, best,
                                          mode);
        rays.exact = geometry::prepare_ray(o, d, tmin, *tmax, mode);
        rays.wide = detail::make_wide_ray(rays.exact);
        if (b.wide.leaf_groups) rays.triangles = geometry::make_triangle4_ray(rays.exact);
    }
    InstanceTrace trace(inst, index, ray.origin, flags, first_hit, tmax, best, rays, plain);
    auto records = [&trace](uint32_t first, uint32_t count) { return trace.records(first, count); };
    if (exhaustive) {
        records(0, uint32_t(b.primitives.size()));
        return trace.found();
    }
    if (!b.wide.leaf_groups) {
        walk_leaves(b.nodes, b.wide, b.primitives, rays.exact, rays.wide, tmax, records, records);
        return trace.found();
    }
    // The float32 mode's own leaf test where the four-triangle ray has the float ray's terms.
    if (mode == TraversalMode::kFloat32 && rays.triangles.usable) {
        auto groups = [&trace](uint32_t first, uint32_t count) __attribute__((always_inline)) {
            return trace.groups_float32(first, count);
        };
        walk_leaves(b.nodes, b.wide, b.groups, rays.exact, rays.wide, tmax, records, groups);
        return trace.found();
    }
    auto groups = [&trace](uint32_t first, uint32_t count) __attribute__((always_inline)) {
        return trace.groups(first, count);
    };
    walk_leaves(b.nodes, b.wide, b.groups, rays.exact, rays.wide, tmax, records, groups);
    return trace.found();
}

// Whether every origin and direction component is finite: such a ray enters a box of infinite
// bounds on every axis (a single-BLAS scene's root) whatever its interval.
// (Three lanes at once: the six scalar tests were 7 instructions a ray more, callgrind.)
bool finite_ray(const Ray& ray) {
    return (detail::finite_lanes(detail::load3(ray.origin)) &
            detail::finite_lanes(detail::load3(ray.direction)) & 7u) == 7u;
}

// trace_scene through the top level's tree (or every instance, exhaustive). Out of line, so
// that its walk's stack and closures stay off the path of single-BLAS scenes.
[[gnu::noinline]] bool trace_top_level(const NvScene::Data& s, const Ray& ray, uint32_t flags,
                                       uint32_t cull_mask, bool first_hit, NvHit* best,
                                       TraversalMode mode, bool exhaustive) {
    const double tmin = ray.tmin;
    double tmax = ray.tmax;
    bool found = false;
    auto instances = [&](uint32_t first, uint32_t count) {
        for (uint32_t k = first; k < first + count; ++k) {
            const Instance& inst = s.instances[k];
            if (!inst.blas || !(inst.mask & cull_mask & 0xFFu)) continue;
            if (trace_instance(inst, k, ray, flags, first_hit, tmin, &tmax, best, mode,
                               exhaustive)) {
                found = true;
                if (first_hit) return true;
            }
        }
        return false;
    };
    if (exhaustive || (s.single_bottom && finite_ray(ray))) {
        instances(0, uint32_t(s.instances.size()));
        return found;
    }
    const double o[3] = {ray.origin[0], ray.origin[1], ray.origin[2]};
    const double d[3] = {ray.direction[0], ray.direction[1], ray.direction[2]};
    const geometry::PreparedRay rd = geometry::prepare_ray(o, d, ray.tmin, ray.tmax, mode);
    walk_leaves(s.nodes, s.wide, s.instances, rd, detail::make_wide_ray(rd), &tmax, instances,
                instances);
    return found;
}

bool trace_scene(const NvScene::Data& s, const Ray& ray, uint32_t flags, uint32_t cull_mask,
                 bool first_hit, NvHit* best, TraversalMode mode, bool exhaustive = false) {
    if (s.nodes.empty() || std::isnan(ray.tmin) || std::isnan(ray.tmax) || !(ray.tmin <= ray.tmax))
        return false;
    // A single-BLAS scene's one instance (open_bottom) straight away: a finite ray enters its
    // root, whatever its interval.
    if (!exhaustive && s.single_bottom && finite_ray(ray)) {
        const Instance& inst = s.instances[0];
        if (!inst.blas || !(inst.mask & cull_mask & 0xFFu)) return false;
        double tmax = ray.tmax;
        return trace_instance(inst, 0, ray, flags, first_hit, ray.tmin, &tmax, best, mode, false);
    }
    return trace_top_level(s, ray, flags, cull_mask, first_hit, best, mode, exhaustive);
}

}  // namespace

NvHit NvScene::closest(const Ray& ray, uint32_t ray_flags, uint32_t cull_mask,
                       TraversalMode mode) const {
    NvHit hit;
    trace_scene(*data_, ray, ray_flags, cull_mask, (ray_flags & kRayFlagTerminateOnFirstHit) != 0,
                &hit, mode);
    return hit;
}

NvHit NvScene::closest_exhaustive(const Ray& ray, uint32_t ray_flags, uint32_t cull_mask,
                                  TraversalMode mode) const {
    NvHit hit;
    trace_scene(*data_, ray, ray_flags, cull_mask, (ray_flags & kRayFlagTerminateOnFirstHit) != 0,
                &hit, mode, true);
    return hit;
}

bool NvScene::any(const Ray& ray, uint32_t ray_flags, uint32_t cull_mask,
                  TraversalMode mode) const {
    return trace_scene(*data_, ray, ray_flags, cull_mask, true, nullptr, mode);
}

}  // namespace clastrace::engine
