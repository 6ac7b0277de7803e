// SPDX-License-Identifier: Apache-2.0
// What serving costs on the host at the pause: executeServedBuild (image of the buffers the
// command reaches, found by re-running) against its peer, engine::execute on an image that
// already holds exactly the memory it needs, and against an image of every buffer of the
// application (the simple exact alternative), as the application's unrelated memory grows.
//
//   served_build_bench [repetitions]
#include "clastrace/capture/cluster_limits.h"
#include "clastrace/capture/served_build.h"

#include <clastrace/engine/execute.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <vector>

using namespace clastrace;
using namespace clastrace::capture;

namespace {

struct HostBuffer {
    std::vector<uint8_t> bytes;
    ServedBuffer view;
};

// `clusters` triangle clusters of 8 x 4 quads (64 triangles, 45 vertices), implicit destinations.
struct Scene {
    std::vector<std::unique_ptr<HostBuffer>> buffers;
    VkClusterAccelerationStructureTriangleClusterInputNV triangles{};
    VkClusterAccelerationStructureCommandsInfoNV command{};
    uint64_t next = 0x10000000;

    uint8_t* add(uint64_t size, VkBufferUsageFlags usage, uint64_t& address) {
        auto b = std::make_unique<HostBuffer>();
        b->bytes.assign(size, 0);
        address = next;
        next += (size + 0xFFFF) / 0x10000 * 0x10000 + 0x10000;
        b->view = {buffers.size() + 1, address, size, usage, b->bytes.data(), buffers.size() + 1};
        buffers.push_back(std::move(b));
        return buffers.back()->bytes.data();
    }

    Scene(uint32_t clusters, uint64_t unrelatedBytes) {
        constexpr uint32_t nx = 8, ny = 4, vertices = (nx + 1) * (ny + 1), triangles_ = 2 * nx * ny;
        triangles.sType =
            VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_TRIANGLE_CLUSTER_INPUT_NV;
        triangles.vertexFormat = VK_FORMAT_R32G32B32_SFLOAT;
        triangles.maxGeometryIndexValue = 0;
        triangles.maxClusterUniqueGeometryCount = 1;
        triangles.maxClusterTriangleCount = triangles_;
        triangles.maxClusterVertexCount = vertices;
        triangles.maxTotalTriangleCount = clusters * triangles_;
        triangles.maxTotalVertexCount = clusters * vertices;
        command.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_COMMANDS_INFO_NV;
        command.input.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_INPUT_INFO_NV;
        command.input.maxAccelerationStructureCount = clusters;
        command.input.opType = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV;
        command.input.opMode = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV;
        command.input.opInput.pTriangleClusters = &triangles;
        VkAccelerationStructureBuildSizesInfoKHR sizes{};
        served_cluster_build_sizes(command.input, sizes);

        const VkBufferUsageFlags in =
            VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_BUILD_INPUT_READ_ONLY_BIT_KHR;
        const VkBufferUsageFlags st = VK_BUFFER_USAGE_ACCELERATION_STRUCTURE_STORAGE_BIT_KHR;
        uint64_t vAddr, iAddr, infoAddr, countAddr;
        auto* v = (float*)add(uint64_t(clusters) * vertices * 12, in, vAddr);
        auto* idx = (uint32_t*)add(uint64_t(clusters) * triangles_ * 12, in, iAddr);
        auto* infos = (VkClusterAccelerationStructureBuildTriangleClusterInfoNV*)add(
            uint64_t(clusters) * sizeof(VkClusterAccelerationStructureBuildTriangleClusterInfoNV),
            in, infoAddr);
        auto* count = (uint32_t*)add(4, in, countAddr);
        *count = clusters;
        for (uint32_t c = 0; c < clusters; ++c) {
            for (uint32_t y = 0; y <= ny; ++y)
                for (uint32_t x = 0; x <= nx; ++x) {
                    float* p = v + (uint64_t(c) * vertices + y * (nx + 1) + x) * 3;
                    p[0] = float(c % 64) * 9.0f + float(x);
                    p[1] = float(c / 64) * 5.0f + float(y);
                    p[2] = float((x * 7 + y * 3 + c) % 5) * 0.25f;
                }
            uint32_t* t = idx + uint64_t(c) * triangles_ * 3;
            for (uint32_t y = 0; y < ny; ++y)
                for (uint32_t x = 0; x < nx; ++x) {
                    const uint32_t q = y * (nx + 1) + x;
                    for (uint32_t i : {q, q + 1, q + nx + 2, q, q + nx + 2, q + nx + 1}) *t++ = i;
                }
            VkClusterAccelerationStructureBuildTriangleClusterInfoNV info{};
            info.clusterID = c;
            info.triangleCount = triangles_;
            info.vertexCount = vertices;
            info.indexType = VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_32BIT_NV;
            info.indexBuffer = iAddr + uint64_t(c) * triangles_ * 12;
            info.vertexBuffer = vAddr + uint64_t(c) * vertices * 12;
            infos[c] = info;
        }
        uint64_t dstA, dstS, implicit, scratch;
        add(uint64_t(clusters) * 8, st, dstA);
        add(uint64_t(clusters) * 4, st, dstS);
        add(sizes.accelerationStructureSize, st, implicit);
        add(sizes.buildScratchSize, VK_BUFFER_USAGE_STORAGE_BUFFER_BIT, scratch);
        command.dstImplicitData = implicit;
        command.scratchData = scratch;
        command.dstAddressesArray = {dstA, 8, uint64_t(clusters) * 8};
        command.dstSizesArray = {dstS, 4, uint64_t(clusters) * 4};
        command.srcInfosArray = {
            infoAddr, sizeof(VkClusterAccelerationStructureBuildTriangleClusterInfoNV),
            uint64_t(clusters) * sizeof(VkClusterAccelerationStructureBuildTriangleClusterInfoNV)};
        command.srcInfosCount = countAddr;
        const uint64_t kPieces = 16;  // an application's other buffers: textures, meshes, uniforms
        for (uint64_t i = 0; unrelatedBytes && i < kPieces; ++i) {
            uint64_t ignored;
            std::memset(add(unrelatedBytes / kPieces, VK_BUFFER_USAGE_STORAGE_BUFFER_BIT, ignored),
                        0x5A, unrelatedBytes / kPieces);
        }
    }
    std::vector<ServedBuffer> views(size_t firstN = ~size_t(0)) const {
        std::vector<ServedBuffer> out;
        for (size_t i = 0; i < buffers.size() && i < firstN; ++i) out.push_back(buffers[i]->view);
        return out;
    }
};

double millis(std::chrono::steady_clock::duration d) {
    return std::chrono::duration<double, std::milli>(d).count();
}

template <class F>
double best(int repetitions, F&& f) {
    double t = 1e30;
    for (int r = 0; r < repetitions; ++r) {
        auto start = std::chrono::steady_clock::now();
        f();
        t = std::min(t, millis(std::chrono::steady_clock::now() - start));
    }
    return t;
}

engine::MemoryImage imageOf(const std::vector<ServedBuffer>& buffers) {
    engine::MemoryImage image;
    for (const ServedBuffer& b : buffers)
        std::memcpy(image.add_region(b.address, b.size, b.usage, "").bytes.data(), b.host, b.size);
    return image;
}

}  // namespace

int main(int argc, char** argv) {
    const int repetitions = argc > 1 ? std::max(1, std::atoi(argv[1])) : 5;
    std::printf(
        "served build on the host (best of %d; ms); peer = engine::execute on a ready image of the "
        "memory it needs\n",
        repetitions);
    std::printf(
        "| clusters | unrelated MiB | engine::execute | served (reached buffers) | runs | all "
        "buffers | served/peer | all/peer |\n");
    std::printf("|---:|---:|---:|---:|---:|---:|---:|---:|\n");
    for (uint32_t clusters : {64u, 1024u, 8192u})
        for (uint64_t unrelatedMiB : {0ull, 64ull, 512ull}) {
            Scene scene(clusters, unrelatedMiB << 20);
            const auto needed = scene.views(8);  // the scene's own buffers come first
            const auto all = scene.views();
            engine::MemoryImage ready = imageOf(needed);
            const double peer = best(repetitions, [&] { engine::execute(scene.command, ready); });
            uint32_t runs = 0;
            const double served = best(repetitions, [&] {
                engine::ObjectDirectory directory;
                ServedExecution e =
                    execute_served_build(scene.command, all, directory, served_engine_properties());
                runs = e.attempts;
                if (!e.ran || !e.record.findings.empty()) {
                    std::fprintf(stderr, "served build failed: %s %s\n", e.error.c_str(),
                                 e.record.findings.empty() ? ""
                                                           : e.record.findings[0].message.c_str());
                    std::exit(1);
                }
            });
            const double whole = best(repetitions, [&] {
                engine::MemoryImage image = imageOf(all);
                engine::execute(scene.command, image);
            });
            std::printf("| %u | %llu | %.2f | %.2f | %u | %.2f | %.2f | %.2f |\n", clusters,
                        (unsigned long long)unrelatedMiB, peer, served, runs, whole, served / peer,
                        whole / peer);
        }
    return 0;
}
