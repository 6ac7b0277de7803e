// SPDX-License-Identifier: Apache-2.0
#include "clastrace/capture/nv_scene_model.h"
#include "clastrace/engine/vertex_format.h"
#include <clastrace/common/hex.h>

#include <algorithm>
#include <cmath>
#include <cstring>

namespace clastrace::capture {
namespace {

const CapturedRange* find_range(const std::vector<CapturedRange>& inputs, MemoryRole role,
                                uint32_t entry) {
    for (const auto& r : inputs)
        if (r.role == role && r.entry == entry) return &r;
    return nullptr;
}

// A KHR build's ranges name their geometry but not their info: the address tells them apart.
const CapturedRange* find_range_at(const std::vector<CapturedRange>& inputs, MemoryRole role,
                                   uint32_t entry, VkDeviceAddress address) {
    for (const auto& r : inputs)
        if (r.role == role && r.entry == entry && r.address == address) return &r;
    return nullptr;
}

float read_float(const CapturedBytes& bytes, size_t offset) {
    float f = 0;
    if (offset + 4 <= bytes.size()) std::memcpy(&f, bytes.data() + offset, 4);
    return f;
}

void grow(NvGeometryModel& g, const float p[3]) {
    for (int k = 0; k < 3; ++k) {
        if (!std::isfinite(p[k])) return;
    }
    for (int k = 0; k < 3; ++k) {
        g.lo[k] = g.bounded ? std::min(g.lo[k], p[k]) : p[k];
        g.hi[k] = g.bounded ? std::max(g.hi[k], p[k]) : p[k];
    }
    g.bounded = true;
}

void transform_point(const float m[12], const float p[3], float out[3]) {
    for (int r = 0; r < 3; ++r)
        out[r] = m[4 * r] * p[0] + m[4 * r + 1] * p[1] + m[4 * r + 2] * p[2] + m[4 * r + 3];
}

// splitmix64: the same rays for the same scene on every machine.
struct Random {
    uint64_t state;
    uint64_t next() {
        uint64_t z = (state += 0x9E3779B97F4A7C15ull);
        z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
        z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
        return z ^ (z >> 31);
    }
    float uniform() { return float(next() >> 40) / float(1 << 24); }
};

// An axis-aligned box in world space, empty until its first point.
struct WorldBox {
    float lo[3] = {0, 0, 0}, hi[3] = {0, 0, 0};
    bool bounded = false;
};

// The eight corners of each bounded geometry of a bottom level through the instance transform.
WorldBox instance_world_box(const NvInstanceRecord& instance,
                            const std::vector<NvGeometryModel>& geometries) {
    WorldBox t;
    for (const NvGeometryModel& g : geometries) {
        if (!g.bounded) continue;
        for (int corner = 0; corner < 8; ++corner) {
            const float p[3] = {corner & 1 ? g.hi[0] : g.lo[0], corner & 2 ? g.hi[1] : g.lo[1],
                                corner & 4 ? g.hi[2] : g.lo[2]};
            float q[3];
            transform_point(instance.transform, p, q);
            for (int k = 0; k < 3; ++k) {
                t.lo[k] = t.bounded ? std::min(t.lo[k], q[k]) : q[k];
                t.hi[k] = t.bounded ? std::max(t.hi[k], q[k]) : q[k];
            }
            t.bounded = true;
        }
    }
    return t;
}

void grow_box(WorldBox& into, const WorldBox& box) {
    for (int k = 0; k < 3; ++k) {
        into.lo[k] = into.bounded ? std::min(into.lo[k], box.lo[k]) : box.lo[k];
        into.hi[k] = into.bounded ? std::max(into.hi[k], box.hi[k]) : box.hi[k];
    }
    into.bounded = true;
}

// A bottom level's geometries join the scene's geometry table the first time an instance names
// it; returns the slot of its geometry 0.
uint32_t geometry_slot_of(uint64_t bottom_level, const std::vector<NvGeometryModel>& geometries,
                          std::map<uint64_t, uint32_t>& first_slot, NvTraceScene& scene) {
    auto [slot, inserted] =
        first_slot.try_emplace(bottom_level, uint32_t(scene.geometry_is_aabb.size()));
    if (inserted)
        for (const NvGeometryModel& g : geometries) {
            scene.geometry_is_aabb.push_back(g.aabbs);
            scene.geometry_first_box.push_back(uint32_t(scene.boxes.size() / 6));
            scene.boxes.insert(scene.boxes.end(), g.boxes.begin(), g.boxes.end());
        }
    return slot->second;
}

// Marks the hit records the instance's geometries use as triangle (0) or box (1) records in
// `recordKind` (-1: unused); false + `why` past the modelled records or on a record used by both.
bool claim_hit_records(const NvInstanceRecord& instance, size_t instance_index,
                       const std::vector<NvGeometryModel>& geometries,
                       std::vector<int>& record_kind, std::string& why) {
    const uint64_t end = uint64_t(instance.sbt_record_offset) + geometries.size();
    if (end > kMaxRayCheckHitRecords) {
        why = "instance " + std::to_string(instance_index) + " uses hit records up to " +
              std::to_string(end) + " (the check models " + std::to_string(kMaxRayCheckHitRecords) +
              ")";
        return false;
    }
    record_kind.resize(std::max(record_kind.size(), size_t(end)), -1);
    for (size_t g = 0; g < geometries.size(); ++g) {
        const int kind = geometries[g].aabbs ? 1 : 0;
        int& used = record_kind[instance.sbt_record_offset + g];
        if (used >= 0 && used != kind) {
            why = "hit record " + std::to_string(instance.sbt_record_offset + g) +
                  " serves both triangle and AABB geometries (the check needs one hit group kind "
                  "per record)";
            return false;
        }
        used = kind;
    }
    return true;
}

// Where the rays start and what they aim at.
struct RayAim {
    std::vector<WorldBox> targets;  // world boxes of the instances a ray can hit
    WorldBox scene;
    float center[3] = {0, 0, 0};
    float radius = 0;
};

void random_unit_vector(Random& random, float d[3]) {
    float len;
    do {
        for (int k = 0; k < 3; ++k) d[k] = 2.0f * random.uniform() - 1.0f;
        len = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    } while (len < 0.05f || len > 1.0f);
    for (int k = 0; k < 3; ++k) d[k] /= len;
}

// From a sphere around the scene towards a random point of `target`.
void aim_at_target(const RayAim& aim, const WorldBox& target, Random& random, NvTracedRay& r,
                   float d[3]) {
    float on_sphere[3], point[3];
    random_unit_vector(random, on_sphere);
    for (int k = 0; k < 3; ++k) {
        r.origin[k] = aim.center[k] + 2.0f * aim.radius * on_sphere[k];
        point[k] = target.lo[k] + (target.hi[k] - target.lo[k]) * random.uniform();
        d[k] = point[k] - r.origin[k];
    }
    const float len = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    for (int k = 0; k < 3; ++k) d[k] = len > 0 ? d[k] / len : (k == 1 ? -1.0f : 0.0f);
}

// From a random point of the scene's box (grown by half) in a random direction.
void aim_anywhere(const RayAim& aim, Random& random, NvTracedRay& r, float d[3]) {
    for (int k = 0; k < 3; ++k) {
        const float half = 0.75f * (aim.scene.hi[k] - aim.scene.lo[k]) + 0.5f;
        r.origin[k] = aim.center[k] - half + 2.0f * half * random.uniform();
    }
    random_unit_vector(random, d);
}

// Even rays come from a sphere around the scene at a random point of an instance's world box;
// odd ones from random points of the scene's box (grown by half) in random directions.
void aim_rays(RayAim& aim, uint32_t ray_count, uint64_t seed, std::vector<NvTracedRay>& rays) {
    for (int k = 0; k < 3; ++k) {
        aim.center[k] = 0.5f * (aim.scene.lo[k] + aim.scene.hi[k]);
        aim.radius = std::max(aim.radius, 0.5f * (aim.scene.hi[k] - aim.scene.lo[k]));
    }
    aim.radius = aim.radius * 1.7320508f + 1.0f;
    Random random{seed};
    for (uint32_t i = 0; i < ray_count; ++i) {
        NvTracedRay r{};
        float d[3];
        if (i % 2 == 0 && !aim.targets.empty())
            aim_at_target(aim, aim.targets[(i / 2) % aim.targets.size()], random, r, d);
        else
            aim_anywhere(aim, random, r, d);
        for (int k = 0; k < 3; ++k) {
            // No exact zero component: the AABB shader's slab test divides by it.
            if (d[k] == 0.0f) d[k] = 1e-7f;
            r.direction[k] = d[k];
        }
        r.t_min = (i % 16 == 7) ? 0.5f * aim.radius : 0.0f;
        r.t_max = (i % 16 == 11) ? 2.5f * aim.radius : 8.0f * aim.radius;
        r.ray_flags = 0;
        r.cull_mask = (i % 8 == 5) ? 0x01u : 0xFFu;
        rays.push_back(r);
    }
}

// VkAccelerationStructureInstanceNV and VkAccelerationStructureInstanceKHR: the same 64 bytes.
NvInstanceRecord instance_from(const uint8_t* p) {
    NvInstanceRecord i;
    std::memcpy(i.transform, p, 48);
    uint32_t a, b;
    std::memcpy(&a, p + 48, 4);
    std::memcpy(&b, p + 52, 4);
    std::memcpy(&i.reference, p + 56, 8);
    i.custom_index = a & 0xFFFFFF;
    i.mask = a >> 24;
    i.sbt_record_offset = b & 0xFFFFFF;
    i.flags = b >> 24;
    return i;
}

void append_instances(const CapturedRange& range, std::vector<NvInstanceRecord>& out) {
    for (size_t at = 0; at + 64 <= range.bytes.size(); at += 64)
        out.push_back(instance_from(range.bytes.data() + at));
}

// `count` boxes of 6 floats, `stride` bytes apart from the start of `range`.
NvGeometryModel aabb_geometry(const CapturedRange* range, uint32_t count, uint64_t stride) {
    NvGeometryModel model;
    model.aabbs = true;
    for (uint32_t i = 0; range && i < count; ++i) {
        const size_t at = size_t(i) * stride;
        float box[6];
        for (int k = 0; k < 6; ++k) box[k] = read_float(range->bytes, at + 4 * k);
        model.boxes.insert(model.boxes.end(), box, box + 6);
        grow(model, box);
        grow(model, box + 3);
    }
    return model;
}

// Grows `model` by up to `count` vertices of `range` through the geometry's transform (a
// VkTransformMatrixKHR, row-major 3x4, when `transform_range` holds one), decoded as the engine
// decodes them. A format the engine's vertex decoder does not read (NV's R16G16B16_SNORM) leaves
// it unbounded: rays are not aimed at it.
void grow_by_vertices(NvGeometryModel& model, const CapturedRange* vertices, VkFormat format,
                      uint64_t stride, uint64_t count, const CapturedRange* transform_range) {
    const engine::VertexFormatInfo info = engine::vertex_format_info(format);
    if (!vertices || !info.supported) return;
    if (stride == 0) stride = info.size;
    float transform[12] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0};
    if (transform_range && transform_range->bytes.size() >= 48)
        std::memcpy(transform, transform_range->bytes.data(), 48);
    const auto* bytes = reinterpret_cast<const std::byte*>(vertices->bytes.data());
    for (uint64_t v = 0; v < count; ++v) {
        const size_t at = size_t(v * stride);
        if (at + info.size > vertices->bytes.size()) break;
        float p[3], q[3];
        engine::decode_vertex(format, bytes + at, p);
        transform_point(transform, p, q);
        grow(model, q);
    }
}

// The geometry one KHR triangles or AABBs geometry of a bottom-level build read, from the ranges
// khr_input_walker.cpp captured at the addresses it read (its ranges rule).
NvGeometryModel khr_geometry(const VkAccelerationStructureGeometryKHR& geometry, uint32_t g,
                             const VkAccelerationStructureBuildRangeInfoKHR& r,
                             const std::vector<CapturedRange>& inputs) {
    if (geometry.geometryType == VK_GEOMETRY_TYPE_AABBS_KHR) {
        const auto& a = geometry.geometry.aabbs;
        return aabb_geometry(find_range_at(inputs, MemoryRole::kAabbs, g,
                                           a.data.deviceAddress + r.primitiveOffset),
                             r.primitiveCount, a.stride ? a.stride : sizeof(VkAabbPositionsKHR));
    }
    NvGeometryModel model;
    if (geometry.geometryType != VK_GEOMETRY_TYPE_TRIANGLES_KHR) return model;
    const auto& t = geometry.geometry.triangles;
    const uint64_t stride =
        t.vertexStride ? t.vertexStride : engine::vertex_format_bytes(t.vertexFormat);
    const bool indexed = t.indexType != VK_INDEX_TYPE_NONE_KHR;
    const VkDeviceAddress first = t.vertexData.deviceAddress + (indexed ? 0 : r.primitiveOffset) +
                                  uint64_t(r.firstVertex) * stride;
    const uint64_t count = indexed ? uint64_t(t.maxVertex) + 1 : uint64_t(r.primitiveCount) * 3;
    const CapturedRange* transform =
        t.transformData.deviceAddress
            ? find_range_at(inputs, MemoryRole::kTransformData, g,
                            t.transformData.deviceAddress + r.transformOffset)
            : nullptr;
    grow_by_vertices(model, find_range_at(inputs, MemoryRole::kVertexBuffer, g, first),
                     t.vertexFormat, stride, count, transform);
    return model;
}

// The instance records a KHR top-level build read: packed, or through an array of pointers.
std::vector<NvInstanceRecord> khr_instances(const VkAccelerationStructureGeometryKHR& geometry,
                                            const VkAccelerationStructureBuildRangeInfoKHR& r,
                                            const std::vector<CapturedRange>& inputs) {
    std::vector<NvInstanceRecord> instances;
    const auto& i = geometry.geometry.instances;
    const VkDeviceAddress at = i.data.deviceAddress + r.primitiveOffset;
    if (!i.arrayOfPointers) {
        if (const CapturedRange* range = find_range_at(inputs, MemoryRole::kInstances, 0, at))
            append_instances(*range, instances);
        return instances;
    }
    const CapturedRange* pointers = find_range_at(inputs, MemoryRole::kInstancePointers, 0, at);
    for (size_t p = 0; pointers && p + 8 <= pointers->bytes.size(); p += 8) {
        VkDeviceAddress address;
        std::memcpy(&address, pointers->bytes.data() + p, 8);
        if (const CapturedRange* one = find_range_at(inputs, MemoryRole::kInstances, 0, address);
            one && one->bytes.size() >= 64)
            instances.push_back(instance_from(one->bytes.data()));
    }
    return instances;
}

}  // namespace

void NvSceneModel::set_handle(uint64_t acceleration_structure, uint64_t device_handle) {
    std::lock_guard lock(mutex_);
    by_device_handle_[device_handle] = acceleration_structure;
    device_handles_[acceleration_structure] = device_handle;
}

void NvSceneModel::forget(uint64_t acceleration_structure) {
    std::lock_guard lock(mutex_);
    bottom_levels_.erase(acceleration_structure);
    top_levels_.erase(acceleration_structure);
    khr_top_levels_.erase(acceleration_structure);
    auto it = device_handles_.find(acceleration_structure);
    if (it == device_handles_.end()) return;
    by_device_handle_.erase(it->second);
    device_handles_.erase(it);
}

void NvSceneModel::observe_build(const BuildAccelerationStructureNVCommand& c,
                                 const std::vector<CapturedRange>& inputs) {
    if (c.type == VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_NV) {
        std::vector<NvInstanceRecord> instances;
        if (const CapturedRange* r = find_range(inputs, MemoryRole::kInstances, 0))
            append_instances(*r, instances);
        std::lock_guard lock(mutex_);
        top_levels_[c.dst] = std::move(instances);
        khr_top_levels_[c.dst] = false;
        return;
    }
    std::vector<NvGeometryModel> geometries(c.geometries.size());
    for (uint32_t g = 0; g < c.geometries.size(); ++g) {
        const VkGeometryNV& geometry = c.geometries[g];
        if (geometry.geometryType == VK_GEOMETRY_TYPE_AABBS_NV) {
            const auto& a = geometry.geometry.aabbs;
            geometries[g] = aabb_geometry(find_range(inputs, MemoryRole::kAabbs, g), a.numAABBs,
                                          a.stride ? a.stride : 24);
            continue;
        }
        const auto& t = geometry.geometry.triangles;
        grow_by_vertices(geometries[g], find_range(inputs, MemoryRole::kVertexBuffer, g),
                         t.vertexFormat, t.vertexStride, t.vertexCount,
                         find_range(inputs, MemoryRole::kTransformData, g));
    }
    std::lock_guard lock(mutex_);
    bottom_levels_[c.dst] = std::move(geometries);
}

void NvSceneModel::observe_khr_build(
    const BuildAccelerationStructuresKHRCommand& c,
    const std::vector<std::vector<VkAccelerationStructureBuildRangeInfoKHR>>& indirect_ranges,
    const std::vector<CapturedRange>& inputs) {
    for (size_t n = 0; n < c.infos.size(); ++n) {
        const KhrBuildInfo& info = c.infos[n];
        static const std::vector<VkAccelerationStructureBuildRangeInfoKHR> kNotRead;
        const auto& ranges = !c.indirect                  ? info.ranges
                             : n < indirect_ranges.size() ? indirect_ranges[n]
                                                          : kNotRead;
        const uint64_t dst = uint64_t(info.info.dstAccelerationStructure);
        if (info.info.type == VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR) {
            std::vector<NvInstanceRecord> instances;
            if (!info.geometries.empty() && !ranges.empty())
                instances = khr_instances(info.geometries[0], ranges[0], inputs);
            std::lock_guard lock(mutex_);
            top_levels_[dst] = std::move(instances);
            khr_top_levels_[dst] = true;
            continue;
        }
        std::vector<NvGeometryModel> geometries(info.geometries.size());
        for (uint32_t g = 0; g < info.geometries.size() && g < ranges.size(); ++g)
            geometries[g] = khr_geometry(info.geometries[g], g, ranges[g], inputs);
        std::lock_guard lock(mutex_);
        bottom_levels_[dst] = std::move(geometries);
    }
}

void NvSceneModel::observe_cluster_blas(uint64_t address,
                                        const std::vector<std::vector<float>>& triangles,
                                        std::vector<std::vector<uint32_t>> geometry_indices) {
    ClusterBlasModel model;
    model.geometries.resize(triangles.size());
    for (size_t g = 0; g < triangles.size(); ++g)
        for (size_t v = 0; v + 3 <= triangles[g].size(); v += 3)
            grow(model.geometries[g], &triangles[g][v]);  // (NaN vertices are left out)
    model.geometry_indices = std::move(geometry_indices);
    std::lock_guard lock(mutex_);
    cluster_blases_[address] = std::move(model);
}

void NvSceneModel::to_cluster_geometry_indices(uint64_t top_level,
                                               std::vector<NvRayHit>& hits) const {
    std::lock_guard lock(mutex_);
    auto top = top_levels_.find(top_level);
    if (top == top_levels_.end()) return;
    for (NvRayHit& h : hits) {
        if (!h.hit || h.instance_id >= top->second.size()) continue;
        const uint64_t reference = top->second[h.instance_id].reference;
        if (by_device_handle_.count(reference)) continue;  // a KHR BLAS: the driver's own index
        auto blas = cluster_blases_.find(reference);
        if (blas == cluster_blases_.end()) continue;
        const auto& indices = blas->second.geometry_indices;
        h.geometry_index =
            h.geometry_index < indices.size() && h.primitive_id < indices[h.geometry_index].size()
                ? indices[h.geometry_index][h.primitive_id]
                : 0xFFFFFFFFu;
    }
}

bool NvSceneModel::is_khr_top_level(uint64_t top_level) const {
    std::lock_guard lock(mutex_);
    auto it = khr_top_levels_.find(top_level);
    return it != khr_top_levels_.end() && it->second;
}

const std::vector<NvGeometryModel>* NvSceneModel::bottom_level_of(uint64_t reference) const {
    if (auto blas = by_device_handle_.find(reference); blas != by_device_handle_.end()) {
        auto model = bottom_levels_.find(blas->second);
        return model == bottom_levels_.end() ? nullptr : &model->second;
    }
    auto cluster_blas = cluster_blases_.find(reference);  // a traceable served cluster BLAS
    return cluster_blas == cluster_blases_.end() ? nullptr : &cluster_blas->second.geometries;
}

bool NvSceneModel::prepare(uint64_t top_level, uint32_t ray_count, NvTraceScene& scene,
                           std::vector<NvTracedRay>& rays, uint64_t& device_handle,
                           std::string& why) const {
    std::lock_guard lock(mutex_);
    scene = {};
    rays.clear();
    auto top = top_levels_.find(top_level);
    if (top == top_levels_.end()) {
        why = "its build's instance records were not captured";
        return false;
    }
    auto kind = khr_top_levels_.find(top_level);
    const bool khr = kind != khr_top_levels_.end() && kind->second;
    auto handle = device_handles_.find(top_level);
    device_handle = handle == device_handles_.end() ? 0 : handle->second;

    std::map<uint64_t, uint32_t> first_slot;  // bottom level (reference) -> its geometry 0's slot
    RayAim aim;
    std::vector<int> record_kind;  // -1 unused, 0 triangles, 1 boxes
    for (size_t i = 0; i < top->second.size(); ++i) {
        const NvInstanceRecord& instance = top->second[i];
        const std::vector<NvGeometryModel>* geometries = bottom_level_of(instance.reference);
        if (!geometries) {
            why = "instance " + std::to_string(i) + " names bottom level handle " +
                  common::hex(instance.reference) + ", whose build the capture did not see";
            return false;
        }
        scene.instances.push_back(
            {instance.sbt_record_offset,
             geometry_slot_of(instance.reference, *geometries, first_slot, scene)});
        // A ray query has no hit groups: only the NV pipeline's records need one kind each.
        if (!khr && !claim_hit_records(instance, i, *geometries, record_kind, why)) return false;
        const WorldBox box = instance_world_box(instance, *geometries);
        if (!box.bounded) continue;
        grow_box(aim.scene, box);
        if (instance.mask != 0) aim.targets.push_back(box);
    }
    for (int kind : record_kind) scene.record_is_procedural.push_back(kind == 1);
    if (!aim.scene.bounded) {
        why = "no instance has bounded geometry to aim rays at";
        return false;
    }
    aim_rays(aim, ray_count, 0x5EEDC1A5ull ^ uint64_t(top->second.size()), rays);
    return true;
}

}  // namespace clastrace::capture
