// SPDX-License-Identifier: Apache-2.0
// Fuzz target (docs/fuzzing.md): arbitrary bytes become a bottom-level build (geometry
// type, counts, format, index type, stride from the first bytes, inputs from the rest),
// a top-level build over it with fuzzed instance records, a deserialization of fuzzed
// serialized data, and a few rays through whatever was built. Nothing may crash, hang, or
// allocate in proportion to a count rather than to memory.
#include "clastrace/engine/nv_build.h"
#include "clastrace/engine/nv_serialize.h"
#include "clastrace/engine/nv_trace.h"

#include <cstddef>
#include <cstdint>
#include <cstring>

using namespace clastrace::engine;

namespace {

struct Reader {
    const uint8_t* p;
    size_t n;
    template <class T>
    T take() {
        T v{};
        const size_t k = sizeof(T) < n ? sizeof(T) : n;
        std::memcpy(&v, p, k);
        p += k;
        n -= k;
        return v;
    }
};

constexpr uint64_t kInput = 0x10000, kObjects = 0x100000, kSerialized = 0x400000;
constexpr uint64_t kObjectSize = 1 << 18;

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    Reader r{data, size};
    const uint8_t kind = r.take<uint8_t>();
    const uint32_t count = r.take<uint16_t>();
    const uint64_t stride = r.take<uint8_t>();
    static const VkFormat formats[] = {VK_FORMAT_R32G32B32_SFLOAT, VK_FORMAT_R32G32_SFLOAT,
                                       VK_FORMAT_R16G16B16_SFLOAT, VK_FORMAT_R16G16_SFLOAT,
                                       VK_FORMAT_R16G16_SNORM,     VK_FORMAT_R16G16B16_SNORM};
    static const VkIndexType index_types[] = {VK_INDEX_TYPE_UINT16, VK_INDEX_TYPE_UINT32,
                                              VK_INDEX_TYPE_NONE_NV};
    MemoryImage memory;
    const size_t rest = r.n;
    memory.add_region(kInput, rest ? rest : 1, 0, "fuzzed input");
    if (rest) std::memcpy(memory.write_bytes(kInput, rest, {}).data(), r.p, rest);
    memory.add_region(kObjects, 3 * kObjectSize, 0, "objects");
    memory.add_region(kSerialized, rest ? rest : 1, 0, "serialized");
    if (rest) std::memcpy(memory.write_bytes(kSerialized, rest, {}).data(), r.p, rest);

    NvBuildCommand blas;
    NvGeometry g;
    g.flags = kind & 1;
    if (kind & 2) {
        g.type = VK_GEOMETRY_TYPE_AABBS_NV;
        g.aabbs = NvAabbs{kInput, rest, 0, count, uint32_t(stride)};
    } else {
        g.triangles.vertex_address = kInput;
        g.triangles.vertex_available = rest;
        g.triangles.vertex_count = count;
        g.triangles.vertex_format = formats[(kind >> 2) % 6];
        g.triangles.vertex_stride = stride;
        g.triangles.index_type = index_types[(kind >> 5) % 3];
        if (g.triangles.index_type != VK_INDEX_TYPE_NONE_NV) {
            g.triangles.index_address = kInput + 7;
            g.triangles.index_count = count;
        }
    }
    blas.info.geometries.push_back(g);
    blas.dst = NvObjectBinding{1, true, kObjects, kObjectSize, std::nullopt, false, 0};
    blas.scratch_address = kInput;
    blas.scratch_available = rest;
    execute_nv_build(blas, memory);

    NvBuildCommand tlas;
    tlas.info.type = VK_ACCELERATION_STRUCTURE_TYPE_TOP_LEVEL_NV;
    tlas.info.instance_count = count % 64;
    tlas.instance_address = kInput;
    tlas.dst =
        NvObjectBinding{2, true, kObjects + kObjectSize, kObjectSize, std::nullopt, false, 0};
    tlas.scratch_address = kInput;
    NvBuildOptions options;
    options.resolve_reference = [](uint64_t h) -> std::optional<uint64_t> {
        return h % 2 ? std::optional<uint64_t>(kObjects) : std::nullopt;
    };
    execute_nv_build(tlas, memory, options);

    NvDeserializeCommand copy;
    copy.src_address = kSerialized;
    copy.dst =
        NvObjectBinding{3, true, kObjects + 2 * kObjectSize, kObjectSize, std::nullopt, false, 0};
    execute_nv_deserialize(copy, memory);

    for (uint64_t at : {kObjects + kObjectSize, kObjects + 2 * kObjectSize}) {
        if (auto scene = NvScene::open(memory, at, nullptr, nullptr))
            for (int k = 0; k < 4; ++k)
                (void)scene->closest(Ray{{float(k), 0.5f, 4}, 0, {0.1f, 0.2f, -1}, 100}, kind,
                                     0xFF);
    }
    if (auto scene = NvScene::open_bottom(memory, kObjects, nullptr))
        (void)scene->any(Ray{{0.5f, 0.5f, 4}, 0, {0, 0, -1}, 100}, 0, 0xFF);
    return 0;
}
