// SPDX-License-Identifier: Apache-2.0
#include "clastrace/testsupport/cluster_scene.h"

#include "clastrace/engine/traversal.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <sstream>

namespace clastrace::testsupport {
namespace {

constexpr uint64_t kVertexBase = 0x1000'0000ull;
constexpr uint64_t kIndexBase = 0x8000'0000ull;
constexpr VkBufferUsageFlags kInputUsage =
    VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR |
    VK_BUFFER_USAGE_SHADER_DEVICE_ADDRESS_BIT;

uint64_t align_up(uint64_t v, uint64_t a) { return (v + a - 1) / a * a; }

}  // namespace

ClusterSceneInputs write_cluster_inputs(const TriangleMesh& mesh,
                                        const std::vector<MeshCluster>& clusters,
                                        const ClusterInputLayout& layout) {
    ClusterSceneInputs out;
    const uint64_t vstride = layout.vertex_stride ? layout.vertex_stride : 12;
    const uint64_t istride = layout.index_stride ? layout.index_stride : layout.index_bytes;
    uint64_t vbytes = 0, ibytes = 0;
    for (const MeshCluster& c : clusters) {
        vbytes += align_up(c.vertices.size() * vstride, 16);
        ibytes += align_up(c.triangles.size() * 3 * istride, 16);
    }
    engine::MemoryRegion& vr =
        out.memory.add_region(kVertexBase, std::max<uint64_t>(vbytes, 16), kInputUsage, "vertices");
    engine::MemoryRegion& ir =
        out.memory.add_region(kIndexBase, std::max<uint64_t>(ibytes, 16), kInputUsage, "indices");
    std::memset(vr.bytes.data(), 0xCD, vr.bytes.size());
    std::memset(ir.bytes.data(), 0xCD, ir.bytes.size());

    out.input.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_TRIANGLE_CLUSTER_INPUT_NV;
    out.input.vertexFormat = VK_FORMAT_R32G32B32_SFLOAT;
    out.input.maxGeometryIndexValue = 0;
    out.input.maxClusterUniqueGeometryCount = 1;
    out.input.minPositionTruncateBitCount = 0;

    uint64_t voff = 0, ioff = 0;
    for (size_t ci = 0; ci < clusters.size(); ++ci) {
        const MeshCluster& c = clusters[ci];
        VkClusterAccelerationStructureBuildTriangleClusterInfoNV info{};
        info.clusterID = uint32_t(ci);
        info.triangleCount = uint32_t(c.triangles.size()) & 0x1FF;
        info.vertexCount = uint32_t(c.vertices.size()) & 0x1FF;
        info.positionTruncateBitCount = layout.truncate_bits & 0x3F;
        info.indexType = layout.index_bytes;  // the flag bits are 1, 2, 4 = the byte counts
        info.baseGeometryIndexAndGeometryFlags.geometryFlags =
            VK_CLUSTER_ACCELERATION_STRUCTURE_GEOMETRY_OPAQUE_BIT_NV;
        info.indexBufferStride = layout.index_stride;
        info.vertexBufferStride = layout.vertex_stride;
        info.vertexBuffer = kVertexBase + voff;
        info.indexBuffer = kIndexBase + ioff;
        for (size_t v = 0; v < c.vertices.size(); ++v)
            std::memcpy(vr.bytes.data() + voff + v * vstride, mesh.positions[c.vertices[v]].data(),
                        12);
        for (size_t t = 0; t < c.triangles.size(); ++t)
            for (int k = 0; k < 3; ++k) {
                const uint32_t idx = c.triangles[t][k];
                std::memcpy(ir.bytes.data() + ioff + (3 * t + k) * istride, &idx,
                            layout.index_bytes);  // little endian
            }
        voff += align_up(c.vertices.size() * vstride, 16);
        ioff += align_up(c.triangles.size() * 3 * istride, 16);
        out.input.maxClusterTriangleCount =
            std::max<uint32_t>(out.input.maxClusterTriangleCount, info.triangleCount);
        out.input.maxClusterVertexCount =
            std::max<uint32_t>(out.input.maxClusterVertexCount, info.vertexCount);
        out.input.maxTotalTriangleCount += info.triangleCount;
        out.input.maxTotalVertexCount += info.vertexCount;
        out.infos.push_back(info);
    }
    return out;
}

ClusterScene build_cluster_scene(const TriangleMesh& mesh, const std::vector<MeshCluster>& clusters,
                                 const ClusterInputLayout& layout) {
    const ClusterSceneInputs in = write_cluster_inputs(mesh, clusters, layout);
    ClusterScene scene;
    const size_t n = clusters.size();
    scene.objects.resize(n);
    scene.findings.resize(n);
    scene.bounds.resize(n);
    scene.positions.resize(n);
    scene.triangles.resize(n);
    engine::ClusterBuilder builder;
    for (size_t ci = 0; ci < n; ++ci) {
        if (!builder.build_triangle_cluster(in.memory, in.infos[ci], in.input, int64_t(ci),
                                            scene.objects[ci], scene.findings[ci]))
            ++scene.failed_builds;
        const MeshCluster& c = clusters[ci];
        for (uint32_t v : c.vertices)
            scene.positions[ci].push_back(
                truncate_position(mesh.positions[v], layout.truncate_bits));
        for (const auto& t : c.triangles) {
            scene.triangles[ci].push_back({t[0], t[1], t[2]});
            for (uint8_t k : t) scene.bounds[ci].extend(scene.positions[ci][k]);
        }
    }
    return scene;
}

void add_to_embree(const ClusterScene& scene, EmbreeReference& embree) {
    for (size_t ci = 0; ci < scene.objects.size(); ++ci)
        embree.add_cluster(scene.positions[ci], scene.triangles[ci]);
    embree.commit();
}

namespace {

// Cluster boxes widened by a relative epsilon, in double: the cull must never drop a cluster
// that a triangle hit lies in.
struct PaddedBox {
    double lo[3], hi[3];
};

std::vector<PaddedBox> padded_boxes(const ClusterScene& scene) {
    std::vector<PaddedBox> out(scene.bounds.size());
    for (size_t c = 0; c < out.size(); ++c)
        for (int k = 0; k < 3; ++k) {
            const double lo = scene.bounds[c].lo[k], hi = scene.bounds[c].hi[k];
            const double pad = 1e-6 * (std::fabs(lo) + std::fabs(hi)) + 1e-30;
            out[c].lo[k] = lo - pad;
            out[c].hi[k] = hi + pad;
        }
    return out;
}

// Entry distance of the ray into the box, or +inf when it misses.
double box_entry(const PaddedBox& b, const double o[3], const double inv[3], double tmin,
                 double tmax) {
    double t0 = tmin, t1 = tmax;
    for (int k = 0; k < 3; ++k) {
        if (std::isinf(inv[k])) {  // direction 0 on this axis
            if (o[k] < b.lo[k] || o[k] > b.hi[k]) return INFINITY;
            continue;
        }
        double a = (b.lo[k] - o[k]) * inv[k], c = (b.hi[k] - o[k]) * inv[k];
        if (a > c) std::swap(a, c);
        t0 = std::max(t0, a);
        t1 = std::min(t1, c);
        if (!(t0 <= t1)) return INFINITY;
    }
    return t0;
}

engine::Ray to_engine(const TestRay& ray) {
    engine::Ray er{};
    for (int k = 0; k < 3; ++k) {
        er.origin[k] = ray.origin[k];
        er.direction[k] = ray.direction[k];
    }
    er.tmin = ray.tmin;
    er.tmax = ray.tmax;
    return er;
}

SceneHit trace_boxes(const ClusterScene& scene, const std::vector<PaddedBox>& boxes,
                     const TestRay& ray) {
    thread_local std::vector<std::pair<double, uint32_t>> order;
    order.clear();
    double o[3], inv[3];
    for (int k = 0; k < 3; ++k) {
        o[k] = ray.origin[k];
        inv[k] = 1.0 / double(ray.direction[k]);  // +-inf for a zero component
    }
    for (uint32_t ci = 0; ci < boxes.size(); ++ci) {
        if (scene.objects[ci].empty()) continue;
        const double e = box_entry(boxes[ci], o, inv, ray.tmin, ray.tmax);
        if (e != INFINITY) order.emplace_back(e, ci);
    }
    std::sort(order.begin(), order.end());
    SceneHit best;
    engine::Ray er = to_engine(ray);
    for (const auto& [entry, ci] : order) {
        if (best.hit && entry > double(best.t) * (1 + 1e-6)) break;
        const engine::Hit h = engine::trace_closest(scene.objects[ci], er, 0);
        // Strictly closer wins: at equal t the cluster met first is kept.
        if (h.hit && (!best.hit || h.t < best.t)) {
            best.hit = true;
            best.t = h.t;
            best.u = h.u;
            best.v = h.v;
            best.cluster = ci;
            best.triangle = h.triangle_index;
            er.tmax = h.t;
        }
    }
    return best;
}

}  // namespace

SceneHit trace_scene(const ClusterScene& scene, const TestRay& ray) {
    return trace_boxes(scene, padded_boxes(scene), ray);
}

bool trace_scene_any(const ClusterScene& scene, const TestRay& ray) {
    const auto boxes = padded_boxes(scene);
    double o[3], inv[3];
    for (int k = 0; k < 3; ++k) {
        o[k] = ray.origin[k];
        inv[k] = 1.0 / double(ray.direction[k]);
    }
    const engine::Ray er = to_engine(ray);
    for (uint32_t ci = 0; ci < boxes.size(); ++ci)
        if (!scene.objects[ci].empty() &&
            box_entry(boxes[ci], o, inv, ray.tmin, ray.tmax) != INFINITY &&
            engine::trace_any(scene.objects[ci], er, 0))
            return true;
    return false;
}

std::string AgreementCounts::summary() const {
    std::ostringstream s;
    s << "rays " << rays << ": agree-miss " << agree_miss << ", agree-hit " << agree_hit << ", tie "
      << tie << ", disagree-hit/miss " << disagree_hit_miss << ", disagree-t " << disagree_t
      << ", disagree-prim " << disagree_prim << ", embree-off " << embree_off << " (t "
      << embree_off_t << ", hit/miss " << embree_off_hit_miss << ", prim " << embree_off_prim
      << "), max rel t error " << max_rel_t_error;
    return s.str();
}

namespace {

std::string describe(const TestRay& r, const SceneHit& e, const ReferenceHit& ref) {
    std::ostringstream s;
    s.precision(9);
    s << "ray o=(" << r.origin[0] << "," << r.origin[1] << "," << r.origin[2] << ") d=("
      << r.direction[0] << "," << r.direction[1] << "," << r.direction[2] << ") engine ";
    if (e.hit)
        s << "hit c" << e.cluster << " t" << e.triangle << " t=" << e.t << " uv=" << e.u << ","
          << e.v;
    else
        s << "miss";
    s << " embree ";
    if (ref.hit)
        s << "hit c" << ref.cluster << " t" << ref.triangle << " t=" << ref.t << " uv=" << ref.u
          << "," << ref.v;
    else
        s << "miss";
    return s.str();
}

// The arbiter: one float triangle against one float ray, in long double.
struct ExactHit {
    bool inside = false;
    long double t = 0, margin = 0;  // margin: min barycentric (negative outside)
};

ExactHit exact_hit(const ClusterScene& scene, uint32_t cluster, uint32_t triangle,
                   const TestRay& r) {
    using L = long double;
    ExactHit out;
    if (cluster >= scene.positions.size() || triangle >= scene.triangles[cluster].size())
        return out;
    const auto& tri = scene.triangles[cluster][triangle];
    const auto& P = scene.positions[cluster];
    L a[3], e1[3], e2[3], d[3], T[3];
    for (int k = 0; k < 3; ++k) {
        a[k] = P[tri[0]][k];
        e1[k] = L(P[tri[1]][k]) - a[k];
        e2[k] = L(P[tri[2]][k]) - a[k];
        d[k] = r.direction[k];
        T[k] = L(r.origin[k]) - a[k];
    }
    auto cross = [](const L* x, const L* y, L* o) {
        o[0] = x[1] * y[2] - x[2] * y[1];
        o[1] = x[2] * y[0] - x[0] * y[2];
        o[2] = x[0] * y[1] - x[1] * y[0];
    };
    auto dot = [](const L* x, const L* y) { return x[0] * y[0] + x[1] * y[1] + x[2] * y[2]; };
    L p[3], q[3];
    cross(d, e2, p);
    const L det = dot(e1, p);
    if (det == 0) return out;
    const L u = dot(T, p) / det;
    cross(T, e1, q);
    const L v = dot(d, q) / det;
    out.t = dot(e2, q) / det;
    out.margin = std::min({u, v, 1 - u - v});
    out.inside = out.margin >= 0 && out.t >= r.tmin && out.t <= r.tmax;
    return out;
}

// Long double leaves about 1e-16 of noise in a margin for well-shaped float input; only a
// verdict well clear of it counts.
constexpr long double kClear = 1e-12L;

bool engine_clearly_right(const ClusterScene& scene, const TestRay& r, const SceneHit& e,
                          const ReferenceHit& ref, double tol) {
    if (e.hit && !ref.hit) {
        const ExactHit x = exact_hit(scene, e.cluster, e.triangle, r);
        return x.inside && x.margin > kClear;
    }
    if (!e.hit && ref.hit) {
        const ExactHit x = exact_hit(scene, ref.cluster, ref.triangle, r);
        return !x.inside && x.margin < -kClear;
    }
    const ExactHit xe = exact_hit(scene, e.cluster, e.triangle, r);
    const long double te_err = std::fabs((long double)e.t - xe.t) / std::fabs(xe.t);
    if (!(xe.inside && xe.margin > kClear && te_err <= tol)) return false;
    if (e.cluster == ref.cluster && e.triangle == ref.triangle) {
        // They differ by more than tol: Embree's is the error when the engine's t sits within a
        // quarter of tol of the exact t (so Embree's own error is at least three quarters of it).
        return te_err <= tol / 4;
    }
    // Different triangles: Embree's is not really hit, or really farther, or (coincident
    // faces) at the same exact t as the engine's while Embree's float t is off.
    const ExactHit xr = exact_hit(scene, ref.cluster, ref.triangle, r);
    return (!xr.inside && xr.margin < -kClear) || xr.t > xe.t * (1 + kClear) ||
           std::fabs(xr.t - xe.t) <= tol * std::fabs(xe.t);
}

std::string arbiter_text(const ClusterScene& scene, const TestRay& r, const SceneHit& e,
                         const ReferenceHit& ref) {
    std::ostringstream s;
    s.precision(12);
    if (e.hit) {
        const ExactHit x = exact_hit(scene, e.cluster, e.triangle, r);
        s << " | arbiter engine-tri: t=" << double(x.t) << " margin=" << double(x.margin);
    }
    if (ref.hit) {
        const ExactHit x = exact_hit(scene, ref.cluster, ref.triangle, r);
        s << " | arbiter embree-tri: t=" << double(x.t) << " margin=" << double(x.margin);
    }
    return s.str();
}

void merge(AgreementCounts& a, const AgreementCounts& b) {
    a.rays += b.rays;
    a.agree_miss += b.agree_miss;
    a.agree_hit += b.agree_hit;
    a.tie += b.tie;
    a.embree_off += b.embree_off;
    a.embree_off_t += b.embree_off_t;
    a.embree_off_hit_miss += b.embree_off_hit_miss;
    a.embree_off_prim += b.embree_off_prim;
    for (const auto& e : b.embree_off_examples)
        if (a.embree_off_examples.size() < 8 || e[0] != 't') a.embree_off_examples.push_back(e);
    a.disagree_hit_miss += b.disagree_hit_miss;
    a.disagree_t += b.disagree_t;
    a.disagree_prim += b.disagree_prim;
    a.max_rel_t_error = std::max(a.max_rel_t_error, b.max_rel_t_error);
    for (const auto& e : b.examples)
        if (a.examples.size() < 8) a.examples.push_back(e);
}

}  // namespace

AgreementCounts compare_with_embree(const ClusterScene& scene, const EmbreeReference& embree,
                                    const std::vector<TestRay>& rays, double tol) {
    const std::vector<PaddedBox> boxes = padded_boxes(scene);
    return tbb::parallel_reduce(
        tbb::blocked_range<size_t>(0, rays.size(), 4096), AgreementCounts{},
        [&](const tbb::blocked_range<size_t>& range, AgreementCounts acc) {
            for (size_t i = range.begin(); i != range.end(); ++i) {
                const TestRay& r = rays[i];
                const SceneHit e = trace_boxes(scene, boxes, r);
                const ReferenceHit ref = embree.intersect(r);
                ++acc.rays;
                if (!e.hit && !ref.hit) {
                    ++acc.agree_miss;
                    continue;
                }
                auto off = [&](const char* what) {
                    if (!engine_clearly_right(scene, r, e, ref, tol)) return false;
                    ++acc.embree_off;
                    ++(what[0] == 't'   ? acc.embree_off_t
                       : what[0] == 'h' ? acc.embree_off_hit_miss
                                        : acc.embree_off_prim);
                    if (acc.embree_off_examples.size() < 8 || what[0] != 't')
                        acc.embree_off_examples.push_back(std::string(what) + ": " +
                                                          describe(r, e, ref) +
                                                          arbiter_text(scene, r, e, ref));
                    return true;
                };
                if (e.hit != ref.hit) {
                    if (off("hit/miss")) continue;
                    ++acc.disagree_hit_miss;
                    if (acc.examples.size() < 8)
                        acc.examples.push_back("hit/miss: " + describe(r, e, ref) +
                                               arbiter_text(scene, r, e, ref));
                    continue;
                }
                const double rel =
                    std::fabs(double(e.t) - ref.t) / std::max(std::fabs(double(ref.t)), 1e-30);
                acc.max_rel_t_error = std::max(acc.max_rel_t_error, rel);
                if (e.cluster == ref.cluster && e.triangle == ref.triangle) {
                    if (rel <= tol)
                        ++acc.agree_hit;
                    else if (!off("t")) {
                        ++acc.disagree_t;
                        if (acc.examples.size() < 8)
                            acc.examples.push_back("t: " + describe(r, e, ref) +
                                                   arbiter_text(scene, r, e, ref));
                    }
                    continue;
                }
                // Another triangle: a tie only if Embree itself meets the engine's triangle at the same t.
                bool tied = false;
                if (rel <= tol)
                    for (const ReferenceHit& h : embree.hits_near(r, ref.t, float(tol)))
                        if (h.cluster == e.cluster && h.triangle == e.triangle) tied = true;
                if (tied)
                    ++acc.tie;
                else if (!off("prim")) {
                    ++acc.disagree_prim;
                    if (acc.examples.size() < 8)
                        acc.examples.push_back("prim: " + describe(r, e, ref) +
                                               arbiter_text(scene, r, e, ref));
                }
            }
            return acc;
        },
        [](AgreementCounts a, const AgreementCounts& b) {
            merge(a, b);
            return a;
        });
}

}  // namespace clastrace::testsupport
