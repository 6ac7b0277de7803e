// SPDX-License-Identifier: Apache-2.0
// engine::execute at scale: CLAS and BLAS builds through execute() for 10^3..10^6 clusters on 1
// and 2 threads, beside Embree building one BVH (RTC_BUILD_QUALITY_LOW) over the same
// triangles in the same process. Each size runs in a forked child so peak RSS is its own.
//
//   engine_execute_bench [max_clusters=1000000] [triangles_per_cluster=64]
#include "clastrace/engine/blas.h"
#include "clastrace/engine/cluster_build.h"
#include "clastrace/engine/execute.h"

#include <embree3/rtcore.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <tbb/task_arena.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <random>
#include <vector>

using namespace clastrace::engine;

namespace {

double now() {
    return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch())
        .count();
}

// Process CPU seconds (all threads): the machine this runs on may be shared, and CPU time
// is what a loaded machine does not inflate.
double cpu() {
    rusage ru{};
    getrusage(RUSAGE_SELF, &ru);
    return double(ru.ru_utime.tv_sec + ru.ru_stime.tv_sec) +
           double(ru.ru_utime.tv_usec + ru.ru_stime.tv_usec) * 1e-6;
}

// n patches of qx*qy quads tiling a bumpy terrain: clusters as a meshlet builder makes them.
struct Scene {
    uint32_t qx = 8, qy = 4;
    std::vector<float> positions;  // per cluster, (qx+1)*(qy+1) vertices
    std::vector<uint8_t> local;    // per cluster, 3 local indices per triangle (same for all)
    uint32_t verts_per_cluster() const { return (qx + 1) * (qy + 1); }
    uint32_t tris_per_cluster() const { return 2 * qx * qy; }
};

Scene make_scene(uint64_t n, uint32_t tris) {
    Scene s;
    s.qx = 8;
    s.qy = std::max<uint32_t>(1, tris / 16);
    const uint64_t side = uint64_t(std::ceil(std::sqrt(double(n))));
    std::mt19937 rng(1);
    std::uniform_real_distribution<float> bump(-0.3f, 0.3f);
    s.positions.reserve(n * s.verts_per_cluster() * 3);
    for (uint64_t c = 0; c < n; ++c) {
        float ox = float(c % side) * s.qx, oy = float(c / side) * s.qy;
        for (uint32_t y = 0; y <= s.qy; ++y)
            for (uint32_t x = 0; x <= s.qx; ++x) {
                float px = ox + x, py = oy + y;
                s.positions.insert(
                    s.positions.end(),
                    {px, py, std::sin(px * 0.05f) * std::cos(py * 0.07f) * 20.0f + bump(rng)});
            }
    }
    for (uint32_t y = 0; y < s.qy; ++y)
        for (uint32_t x = 0; x < s.qx; ++x) {
            uint8_t a = uint8_t(y * (s.qx + 1) + x), b = uint8_t(a + 1), c = uint8_t(a + s.qx + 1),
                    d = uint8_t(c + 1);
            s.local.insert(s.local.end(), {a, b, d, a, d, c});
        }
    return s;
}

struct Row {
    double clas_s[2], blas_s[2], embree_s[2];
    double clas_cpu[2], blas_cpu[2], embree_cpu[2];
    uint64_t clas_bytes, blas_bytes;
    long peak_kib;
};

VkClusterAccelerationStructureCommandsInfoNV command(VkClusterAccelerationStructureOpTypeNV type,
                                                     uint32_t count, uint64_t infos,
                                                     uint64_t implicit, uint64_t addresses,
                                                     uint64_t sizes, uint64_t scratch,
                                                     void* input) {
    VkClusterAccelerationStructureCommandsInfoNV c{};
    c.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_COMMANDS_INFO_NV;
    c.input.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_INPUT_INFO_NV;
    c.input.maxAccelerationStructureCount = count;
    c.input.opType = type;
    c.input.opMode = VK_CLUSTER_ACCELERATION_STRUCTURE_OP_MODE_IMPLICIT_DESTINATIONS_NV;
    if (type == VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV)
        c.input.opInput.pClustersBottomLevel =
            static_cast<VkClusterAccelerationStructureClustersBottomLevelInputNV*>(input);
    else
        c.input.opInput.pTriangleClusters =
            static_cast<VkClusterAccelerationStructureTriangleClusterInputNV*>(input);
    c.dstImplicitData = implicit;
    c.scratchData = scratch;
    c.dstAddressesArray = {addresses, 8, 8ull * count};
    c.dstSizesArray = {sizes, 4, 4ull * count};
    c.srcInfosArray = {infos, 0, 0};
    return c;
}

Row run(uint64_t n, uint32_t tris) {
    Row row{};
    Scene s = make_scene(n, tris);
    const uint32_t V = s.verts_per_cluster(), T = s.tris_per_cluster();
    const uint64_t kInputs = 0x1000000000ull, kObjects = 0x2000000000ull, kArrays = 0x3000000000ull,
                   kScratch = 0x4000000000ull, kBlas = 0x5000000000ull;
    MemoryImage mem;
    const uint64_t vb_bytes = s.positions.size() * 4, ib_bytes = (s.local.size() + 255) / 256 * 256;
    const uint64_t info_bytes =
        n * sizeof(VkClusterAccelerationStructureBuildTriangleClusterInfoNV);
    mem.add_region(kInputs, vb_bytes + ib_bytes + info_bytes + 4096, 0, "inputs");
    std::memcpy(mem.write_bytes(kInputs, vb_bytes, {}).data(), s.positions.data(), vb_bytes);
    const uint64_t ib = kInputs + vb_bytes;
    std::memcpy(mem.write_bytes(ib, s.local.size(), {}).data(), s.local.data(), s.local.size());
    const uint64_t infos = ib + ib_bytes;
    {
        auto out = mem.write_bytes(infos, info_bytes, {});
        for (uint64_t c = 0; c < n; ++c) {
            VkClusterAccelerationStructureBuildTriangleClusterInfoNV info{};
            info.clusterID = uint32_t(c);
            info.triangleCount = T;
            info.vertexCount = V;
            info.indexType = VK_CLUSTER_ACCELERATION_STRUCTURE_INDEX_FORMAT_8BIT_NV;
            info.indexBufferStride = 1;
            info.vertexBufferStride = 12;
            info.indexBuffer = ib;  // every cluster shares the same local topology
            info.vertexBuffer = kInputs + c * V * 12;
            std::memcpy(out.data() + c * sizeof info, &info, sizeof info);
        }
    }
    VkClusterAccelerationStructureTriangleClusterInputNV in{};
    in.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_TRIANGLE_CLUSTER_INPUT_NV;
    in.vertexFormat = VK_FORMAT_R32G32B32_SFLOAT;
    in.maxGeometryIndexValue = 0;
    in.maxClusterUniqueGeometryCount = 1;
    in.maxClusterTriangleCount = T;
    in.maxClusterVertexCount = V;
    in.maxTotalTriangleCount = uint32_t(std::min<uint64_t>(n * T, 0xFFFFFFFFu));
    in.maxTotalVertexCount = uint32_t(std::min<uint64_t>(n * V, 0xFFFFFFFFu));
    EngineProperties props;
    mem.add_region(kObjects,
                   n * (max_cluster_object_size(in, props, false) + props.cluster_byte_alignment),
                   0, "clas");
    mem.add_region(kArrays, n * 12 + 64, 0, "arrays");
    mem.add_region(kScratch, n * 16 + 256, 0, "scratch");
    const uint64_t addresses = kArrays, sizes = kArrays + n * 8;
    VkClusterAccelerationStructureClustersBottomLevelInputNV bl{};
    bl.sType = VK_STRUCTURE_TYPE_CLUSTER_ACCELERATION_STRUCTURE_CLUSTERS_BOTTOM_LEVEL_INPUT_NV;
    bl.maxTotalClusterCount = uint32_t(n);
    bl.maxClusterCountPerAccelerationStructure = uint32_t(n);
    mem.add_region(kBlas, bottom_level_size_bound(n) + 1024, 0, "blas");
    const uint64_t blas_info =
        kBlas + bottom_level_size_bound(n) + 256;  // after the object's worst case
    for (int t = 0; t < 2; ++t) {
        tbb::task_arena arena(t + 1);
        ExecutionRecord r;
        auto cc = command(VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_TRIANGLE_CLUSTER_NV,
                          uint32_t(n), infos, kObjects, addresses, sizes, kScratch, &in);
        double t0 = now(), c0 = cpu();
        arena.execute([&] { r = execute(cc, mem); });
        row.clas_s[t] = now() - t0;
        row.clas_cpu[t] = cpu() - c0;
        if (!r.findings.empty())
            std::fprintf(stderr, "CLAS findings: %s\n", r.findings[0].message.c_str());
        row.clas_bytes = r.implicit_bytes_used;
        VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV bi{uint32_t(n), 8, addresses};
        mem.write(blas_info, bi, {});
        auto bc = command(VK_CLUSTER_ACCELERATION_STRUCTURE_OP_TYPE_BUILD_CLUSTERS_BOTTOM_LEVEL_NV,
                          1, blas_info, kBlas, kScratch + n * 16 + 64, kScratch + n * 16 + 72,
                          kScratch, &bl);
        bc.dstAddressesArray = {kArrays + n * 12, 8, 8};  // spare 64 bytes at the end of arrays
        bc.dstSizesArray = {kArrays + n * 12 + 8, 4, 4};
        t0 = now();
        c0 = cpu();
        arena.execute([&] { r = execute(bc, mem); });
        row.blas_s[t] = now() - t0;
        row.blas_cpu[t] = cpu() - c0;
        if (!r.findings.empty())
            std::fprintf(stderr, "BLAS findings: %s\n", r.findings[0].message.c_str());
        row.blas_bytes = r.implicit_bytes_used;
    }
    // Embree over the same triangles, one BVH, low quality, 1 and 2 threads.
    std::vector<uint32_t> idx;
    idx.reserve(n * T * 3);
    for (uint64_t c = 0; c < n; ++c)
        for (uint8_t l : s.local) idx.push_back(uint32_t(c * V + l));
    for (int t = 0; t < 2; ++t) {
        char cfg[64];
        std::snprintf(cfg, sizeof cfg, "threads=%d", t + 1);
        RTCDevice dev = rtcNewDevice(cfg);
        RTCScene scene = rtcNewScene(dev);
        rtcSetSceneBuildQuality(scene, RTC_BUILD_QUALITY_LOW);
        RTCGeometry g = rtcNewGeometry(dev, RTC_GEOMETRY_TYPE_TRIANGLE);
        rtcSetSharedGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                   s.positions.data(), 0, 12, s.positions.size() / 3);
        rtcSetSharedGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, idx.data(), 0, 12,
                                   idx.size() / 3);
        rtcSetGeometryBuildQuality(g, RTC_BUILD_QUALITY_LOW);
        rtcCommitGeometry(g);
        rtcAttachGeometry(scene, g);
        rtcReleaseGeometry(g);
        double t0 = now(), c0 = cpu();
        rtcCommitScene(scene);
        row.embree_s[t] = now() - t0;
        row.embree_cpu[t] = cpu() - c0;
        rtcReleaseScene(scene);
        rtcReleaseDevice(dev);
    }
    rusage ru{};
    getrusage(RUSAGE_SELF, &ru);
    row.peak_kib = ru.ru_maxrss;
    return row;
}

}  // namespace

int main(int argc, char** argv) {
    uint64_t max_n = argc > 1 ? std::strtoull(argv[1], nullptr, 10) : 1000000;
    uint32_t tris = argc > 2 ? uint32_t(std::strtoul(argv[2], nullptr, 10)) : 64;
    std::printf(
        "engine::execute on %u-triangle clusters (implicit destinations), vs Embree 3 one BVH over "
        "the same "
        "triangles (RTC_BUILD_QUALITY_LOW)\n\n",
        tris);
    std::printf(
        "Wall-clock columns, then CPU seconds of the process (the machine may be shared; CPU time "
        "is not "
        "inflated by other load). Ratios < 1: the engine faster.\n\n");
    std::printf(
        "| clusters | threads | CLAS ops/s | CLAS Mtris/s | BLAS ms | Embree ms | BLAS/Embree | "
        "CLAS+BLAS/Embree | CLAS cpu s | BLAS cpu ms | Embree cpu ms | BLAS cpu us/(n log2 n) | "
        "peak RSS MiB |\n");
    std::printf("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n");
    for (uint64_t n = 1000; n <= max_n; n *= 10) {
        int fds[2];
        if (pipe(fds) != 0) return 1;
        pid_t pid = fork();
        if (pid == 0) {
            close(fds[0]);
            Row r = run(n, tris);
            if (write(fds[1], &r, sizeof r) != ssize_t(sizeof r)) _exit(1);
            _exit(0);
        }
        close(fds[1]);
        Row r{};
        ssize_t got = read(fds[0], &r, sizeof r);
        close(fds[0]);
        int status = 0;
        waitpid(pid, &status, 0);
        if (got != ssize_t(sizeof r) || !WIFEXITED(status) || WEXITSTATUS(status) != 0) {
            std::printf("| %llu | - | did not finish (status %d: out of memory or killed) |\n",
                        (unsigned long long)n, status);
            break;
        }
        const double tri_count = double(n) * tris;
        for (int t = 0; t < 2; ++t) {
            std::printf(
                "| %llu | %d | %.0f | %.2f | %.1f | %.1f | %.2f | %.2f | %.2f | %.1f | %.1f | %.4f "
                "| %.0f |\n",
                (unsigned long long)n, t + 1, double(n) / r.clas_s[t],
                tri_count / r.clas_s[t] / 1e6, r.blas_s[t] * 1e3, r.embree_s[t] * 1e3,
                r.blas_s[t] / r.embree_s[t], (r.clas_s[t] + r.blas_s[t]) / r.embree_s[t],
                r.clas_cpu[t], r.blas_cpu[t] * 1e3, r.embree_cpu[t] * 1e3,
                r.blas_cpu[t] * 1e6 / (double(n) * std::log2(double(n))),
                double(r.peak_kib) / 1024.0);
        }
        std::fflush(stdout);
    }
    return 0;
}
