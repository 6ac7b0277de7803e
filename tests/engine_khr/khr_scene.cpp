// SPDX-License-Identifier: Apache-2.0
#include "khr_scene.h"

#include <cstring>

namespace clastrace::khrtest {

eng::KhrObject make_object(NvWorld& w, VkAccelerationStructureTypeKHR type, uint64_t size) {
    eng::KhrObject o;
    o.address = w.alloc(size, "acceleration structure");
    o.handle = o.address;
    o.size = size;
    o.type = type;
    return o;
}

namespace {

// Bytes of junk (0xA5) followed by `data`: what a primitiveOffset or firstVertex skips.
uint64_t put_after_junk(NvWorld& w, const void* data, uint64_t size, uint64_t junk,
                        const std::string& label) {
    std::vector<uint8_t> bytes(junk + size, 0xA5);
    if (size) std::memcpy(bytes.data() + junk, data, size);
    return w.put(bytes.data(), bytes.size(), label);
}

eng::KhrGeometry triangles(NvWorld& w, const nvtest::GeometrySpec& g, const Layout& layout,
                           eng::KhrBuildRange& range) {
    eng::KhrGeometry geo;
    geo.type = VK_GEOMETRY_TYPE_TRIANGLES_KHR;
    geo.flags = g.flags;
    eng::KhrTriangles& t = geo.triangles;
    range.primitive_count = uint32_t(g.mesh.triangles.size());
    range.first_vertex = layout.first_vertex;
    if (layout.no_indices) {
        std::vector<ts::Float3> expanded;
        for (const auto& tri : g.mesh.triangles)
            for (uint32_t k : tri) expanded.push_back(g.mesh.positions[k]);
        t.vertex_data =
            put_after_junk(w, expanded.data(), expanded.size() * 12,
                           layout.primitive_offset + 12ull * layout.first_vertex, "vertices");
        t.max_vertex = uint32_t(expanded.size() + layout.first_vertex - 1);
    } else {
        t.vertex_data = put_after_junk(w, g.mesh.positions.data(), g.mesh.positions.size() * 12,
                                       12ull * layout.first_vertex, "vertices");
        t.max_vertex = uint32_t(g.mesh.positions.size() + layout.first_vertex - 1);
        t.index_type = layout.uint16_indices ? VK_INDEX_TYPE_UINT16 : VK_INDEX_TYPE_UINT32;
        std::vector<uint8_t> indices;
        for (const auto& tri : g.mesh.triangles)
            for (uint32_t k : tri) {
                const size_t at = indices.size();
                indices.resize(at + (layout.uint16_indices ? 2 : 4));
                if (layout.uint16_indices) {
                    const uint16_t s = uint16_t(k);
                    std::memcpy(indices.data() + at, &s, 2);
                } else {
                    std::memcpy(indices.data() + at, &k, 4);
                }
            }
        t.index_data =
            put_after_junk(w, indices.data(), indices.size(), layout.primitive_offset, "indices");
    }
    range.primitive_offset = layout.primitive_offset;
    if (layout.identity_transform) {
        const float m[12] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0};
        t.transform_data = put_after_junk(w, m, 48, 16, "transform");
        range.transform_offset = 16;
    }
    return geo;
}

}  // namespace

eng::KhrBuildInfo blas_info(NvWorld& w, const BlasSpec& spec, const Layout& layout,
                            VkBuildAccelerationStructureFlagsKHR flags) {
    eng::KhrBuildInfo info;
    info.type = VK_ACCELERATION_STRUCTURE_TYPE_BOTTOM_LEVEL_KHR;
    info.flags = flags;
    for (const nvtest::GeometrySpec& g : spec.geometries) {
        eng::KhrBuildRange range;
        if (spec.aabbs) {
            eng::KhrGeometry geo;
            geo.type = VK_GEOMETRY_TYPE_AABBS_KHR;
            geo.flags = g.flags;
            geo.aabbs.stride = 32;  // padded records
            std::vector<float> boxes;
            for (const auto& b : g.boxes) {
                boxes.insert(boxes.end(), b.begin(), b.end());
                boxes.insert(boxes.end(), {0.0f, 0.0f});
            }
            geo.aabbs.data =
                put_after_junk(w, boxes.data(), boxes.size() * 4, layout.primitive_offset, "aabbs");
            range.primitive_count = uint32_t(g.boxes.size());
            range.primitive_offset = layout.primitive_offset;
            info.geometries.push_back(geo);
        } else {
            info.geometries.push_back(triangles(w, g, layout, range));
        }
        info.ranges.push_back(range);
    }
    return info;
}

eng::KhrBuildInfo tlas_info(uint64_t instance_data, uint32_t count, bool pointers,
                            VkBuildAccelerationStructureFlagsKHR flags) {
    eng::KhrBuildInfo info;
    info.type = VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_KHR;
    info.flags = flags;
    eng::KhrGeometry geo;
    geo.type = VK_GEOMETRY_TYPE_INSTANCES_KHR;
    geo.instances.data = instance_data;
    geo.instances.array_of_pointers = pointers;
    info.geometries.push_back(geo);
    info.ranges.push_back(eng::KhrBuildRange{count, 0, 0, 0});
    return info;
}

eng::ExecutionRecord build(NvWorld& w, eng::KhrBuildInfo& info,
                           const eng::KhrBuildOptions& options) {
    std::vector<uint32_t> counts;
    for (const auto& r : info.ranges) counts.push_back(r.primitive_count);
    const eng::KhrBuildSizes sizes = eng::khr_build_sizes(info.type, info.geometries, counts);
    if (info.dst.handle == 0)
        info.dst = make_object(w, info.type, sizes.acceleration_structure_size);
    const bool update = info.mode == VK_BUILD_ACCELERATION_STRUCTURE_MODE_UPDATE_KHR;
    const uint64_t s = update ? sizes.update_scratch_size : sizes.build_scratch_size;
    info.scratch_address = w.alloc(s, "scratch");
    info.scratch_available = s;
    return eng::execute_khr_build(eng::KhrBuildCommand{{info}}, w.memory, options);
}

uint64_t put_instances(NvWorld& w, const std::vector<InstanceSpec>& instances,
                       const std::vector<uint64_t>& blas_addresses, bool pointers) {
    const std::vector<uint8_t> bytes = w.instance_bytes(instances, blas_addresses);
    if (!pointers) return w.put(bytes.data(), bytes.size(), "instances");
    std::vector<uint64_t> addresses;
    for (size_t i = 0; i < instances.size(); ++i)  // one record per buffer, scattered
        addresses.push_back(w.put(bytes.data() + 64 * i, 64, "instance"));
    return w.put(addresses.data(), addresses.size() * 8, "instance pointers");
}

std::unique_ptr<KhrScene> build_scene(const std::vector<BlasSpec>& blas,
                                      const std::vector<InstanceSpec>& instances,
                                      const Layout& layout,
                                      VkBuildAccelerationStructureFlagsKHR flags) {
    auto s = std::make_unique<KhrScene>();
    auto note = [&](const eng::ExecutionRecord& r) {
        for (const auto& f : r.findings) s->findings.push_back(f.rule + ": " + f.message);
    };
    std::vector<uint64_t> addresses;
    for (const BlasSpec& b : blas) {
        eng::KhrBuildInfo info = blas_info(s->world, b, layout, flags);
        note(build(s->world, info));
        s->blas.push_back(info.dst);
        addresses.push_back(info.dst.address);
    }
    const uint64_t data = put_instances(s->world, instances, addresses, layout.instance_pointers);
    eng::KhrBuildInfo top =
        tlas_info(data, uint32_t(instances.size()), layout.instance_pointers, flags);
    note(build(s->world, top));
    s->tlas = top.dst;
    return s;
}

bool has(const eng::ExecutionRecord& r, const std::string& rule) {
    for (const auto& f : r.findings)
        if (f.rule == rule) return true;
    return false;
}

}  // namespace clastrace::khrtest
