// SPDX-License-Identifier: Apache-2.0
// cluster_scene: a sample application for VK_NV_cluster_acceleration_structure.
//
// Loads an OBJ mesh, clusters it with meshoptimizer and runs every op of the extension over
// it in one command buffer: cluster sizes (compute-sizes mode), clusters, templates, their
// instantiation, template indices, a move of the clusters and two bottom-level structures.
// The src infos reach the GPU through vkCmdCopyBuffer in the same command buffer. It then
// reads back what each build wrote and prints it. On a driver without the extension, run it
// under the capture layer, which serves it: `clastrace capture -o scene.clt -- cluster_scene`.
#include "cluster_scene.h"
#include "mesh_clusters.h"
#include "obj_mesh.h"
#include "vulkan_context.h"

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <barrier>
#include <cinttypes>
#include <cstdio>
#include <exception>
#include <thread>

namespace {

using namespace cluster_scene;

constexpr const char* kDefaultMesh = "/usr/share/assimp/models/OBJ/WusonOBJ.obj";
constexpr int kExitFailure = 2, kExitNoExtension = 3;

const char* opTypeName(uint32_t type) {
    static const char* names[] = {"move",     "bottom-level", "triangle-cluster",
                                  "template", "instantiate",  "template-indices"};
    return type < 6 ? names[type] : "?";
}
const char* opModeName(uint32_t mode) {
    static const char* names[] = {"implicit", "explicit", "compute-sizes"};
    return mode < 3 ? names[mode] : "?";
}

std::string hex64(uint64_t v) {
    char text[24];
    std::snprintf(text, sizeof text, "0x%016" PRIx64, v);
    return text;
}

nlohmann::json toJson(const SceneResult& scene) {
    nlohmann::json builds = nlohmann::json::array();
    for (const BuildOutputs& b : scene.outputs) {
        nlohmann::json digests = nlohmann::json::array();
        for (uint64_t d : b.objectDigests) digests.push_back(hex64(d));
        builds.push_back({{"label", b.label},
                          {"opType", b.opType},
                          {"opTypeName", opTypeName(b.opType)},
                          {"opMode", b.opMode},
                          {"opModeName", opModeName(b.opMode)},
                          {"ops", b.ops},
                          {"dstAddressesArray", b.dstAddressesArray},
                          {"dstSizesArray", b.dstSizesArray},
                          {"dstImplicitData", b.dstImplicitData},
                          {"addresses", b.addresses},
                          {"sizes", b.sizes},
                          {"objectDigests", digests},
                          {"addressesBytes", b.addressesHex},
                          {"sizesBytes", b.sizesHex}});
    }
    return {{"commandBuffer", scene.commandBuffer},
            {"commands", scene.commands},
            {"computeWrites", scene.computeWrites},
            {"counts",
             {{"copies", scene.copies},
              {"dispatches", scene.dispatches},
              {"barriers", scene.barriers},
              {"builds", scene.builds}}},
            {"builds", builds}};
}

void printText(const SceneResult& scene, size_t index) {
    std::printf("command buffer %zu: %u copies, %u dispatches, %u barriers, %u builds\n", index,
                scene.copies, scene.dispatches, scene.barriers, scene.builds);
    for (const BuildOutputs& b : scene.outputs) {
        uint64_t bytes = 0, digest = 0xcbf29ce484222325ull;
        for (uint32_t s : b.sizes) bytes += s;
        for (uint64_t d : b.objectDigests)
            digest = fnv1a64(reinterpret_cast<const uint8_t*>(&d), 8) ^ (digest * 31);
        std::printf("  %-17s %-16s %-13s ops %3u  bytes %8" PRIu64, b.label.c_str(),
                    opTypeName(b.opType), opModeName(b.opMode), b.ops, bytes);
        if (!b.addresses.empty())
            std::printf("  first %s  objects digest %s", hex64(b.addresses[0]).c_str(),
                        hex64(digest).c_str());
        std::printf("\n");
    }
}

// The command line, as parsed.
struct CommandLine {
    std::string meshPath = kDefaultMesh;
    uint32_t maxClusters = 0, clusterVertices = 64, clusterTriangles = 124, threads = 1, tile = 1;
    std::vector<std::string> skip;
    bool listBarriers = false, json = false, computeInfos = false, computeElsewhere = false;
};

void addOptions(CLI::App& app, CommandLine& c) {
    app.add_option("mesh", c.meshPath, "OBJ file to cluster")->capture_default_str();
    app.add_option("--max-clusters", c.maxClusters, "build only the first N clusters (0: all)")
        ->capture_default_str();
    app.add_option("--tile", c.tile,
                   "the mesh this many times side by side (1 to 64): a large scene from a small "
                   "file")
        ->check(CLI::Range(1u, 64u))
        ->capture_default_str();
    app.add_option("--cluster-vertices", c.clusterVertices, "vertices per cluster, at most")
        ->check(CLI::Range(3u, 255u))
        ->capture_default_str();
    app.add_option("--cluster-triangles", c.clusterTriangles,
                   "triangles per cluster, at most (a multiple of 4)")
        ->check(CLI::Range(4u, 256u))
        ->capture_default_str();
    app.add_option("--skip-barrier", c.skip,
                   "leave out the barrier NAME (repeatable; --list-barriers prints the names)");
    app.add_flag("--compute-infos", c.computeInfos,
                 "write the cluster infos and their count with a compute dispatch through buffer "
                 "device addresses (push constants) instead of vkCmdCopyBuffer; their barrier is "
                 "dispatch-to-sizes (--list-barriers --compute-infos)");
    app.add_flag("--compute-elsewhere", c.computeElsewhere,
                 "with --compute-infos: a second dispatch copies the cluster infos into a buffer "
                 "no command reads, with no barrier after it (its writes reach no build)")
        ->needs("--compute-infos");
    app.add_flag("--list-barriers", c.listBarriers,
                 "print the barriers that can be left out and exit");
    app.add_option("--threads", c.threads,
                   "record this many command buffers on as many threads (1 or 2)")
        ->check(CLI::Range(1u, 2u))
        ->capture_default_str();
    app.add_flag("--json", c.json, "print one JSON object with everything the builds wrote");
}

// One scene a thread, each recorded (and submitted) on its own command buffer from its own pool.
std::vector<SceneResult> runScenes(VulkanContext& context, const ClusteredMesh& clusters,
                                   const SceneOptions& options, uint32_t threads) {
    std::vector<SceneResult> scenes(threads);
    if (threads == 1) {
        scenes[0] = runScene(context, clusters, options);
        return scenes;
    }
    // The threads start recording together so the layer sees the calls interleaved.
    std::barrier<> start{std::ptrdiff_t(threads)};
    std::vector<std::exception_ptr> failures(threads);
    std::vector<std::thread> workers;
    for (uint32_t t = 0; t < threads; ++t)
        workers.emplace_back([&, t] {
            SceneOptions mine = options;
            mine.queueIndex = t;
            mine.beforeRecording = [&] { start.arrive_and_wait(); };
            try {
                scenes[t] = runScene(context, clusters, mine);
            } catch (...) {
                failures[t] = std::current_exception();
                // Harmless if it already arrived: the run is failing anyway.
                start.arrive_and_drop();
            }
        });
    for (auto& w : workers) w.join();
    for (auto& f : failures)
        if (f) std::rethrow_exception(f);
    return scenes;
}

void printScenes(const CommandLine& c, const TriangleMesh& mesh, const ClusteredMesh& clusters,
                 const VulkanContext& context, const std::vector<SceneResult>& scenes) {
    if (c.json) {
        nlohmann::json out = {{"mesh", c.meshPath},
                              {"device", context.deviceName()},
                              {"vertices", mesh.vertexCount()},
                              {"triangles", mesh.triangleCount()},
                              {"clusters", clusters.clusters.size()},
                              {"clusterVertices", clusters.totalVertices()},
                              {"clusterTriangles", clusters.totalTriangles()},
                              {"queues", context.queueCount()},
                              {"skippedBarriers", c.skip},
                              {"computeInfos", c.computeInfos},
                              {"scenes", nlohmann::json::array()}};
        for (const SceneResult& s : scenes) out["scenes"].push_back(toJson(s));
        std::printf("%s\n", out.dump(1).c_str());
        return;
    }
    std::printf(
        "%s: %zu vertices, %zu triangles -> %zu clusters (%u vertices, %u triangles) on %s\n",
        c.meshPath.c_str(), mesh.vertexCount(), mesh.triangleCount(), clusters.clusters.size(),
        clusters.totalVertices(), clusters.totalTriangles(), context.deviceName().c_str());
    for (size_t i = 0; i < scenes.size(); ++i) printText(scenes[i], i);
}

int run(const CommandLine& c) {
    TriangleMesh mesh;
    std::string error;
    if (!loadObj(c.meshPath, mesh, error)) {
        std::fprintf(stderr, "cluster_scene: %s\n", error.c_str());
        return kExitFailure;
    }
    tileMesh(mesh, c.tile);
    const ClusteredMesh clusters =
        clusterMesh(mesh, c.clusterVertices, c.clusterTriangles, c.maxClusters);
    VulkanContext context;
    SceneOptions options;
    options.skipBarriers = {c.skip.begin(), c.skip.end()};
    options.computeInfos = c.computeInfos;
    options.computeElsewhere = c.computeElsewhere;
    const std::vector<SceneResult> scenes = runScenes(context, clusters, options, c.threads);
    printScenes(c, mesh, clusters, context, scenes);
    return 0;
}

}  // namespace

int main(int argc, char** argv) {
    CLI::App app{
        "cluster_scene: every op of VK_NV_cluster_acceleration_structure over a clustered OBJ "
        "mesh, with src infos "
        "written by GPU copies and the barriers they need. Without the extension in the driver, "
        "run it under the "
        "capture layer: clastrace capture -o scene.clt -- cluster_scene"};
    CommandLine c;
    addOptions(app, c);
    try {
        app.parse(argc, argv);
    } catch (const CLI::ParseError& e) {
        const int code = app.exit(e);  // prints the help or the error
        return code == 0 ? 0 : 1;      // a usage error (README: exit codes)
    }
    if (c.listBarriers) {
        for (const BarrierInfo& b : barrierCatalogue(c.computeInfos))
            std::printf("%-30s %s\n", b.name, b.orders);
        return 0;
    }
    if (c.clusterTriangles % 4 != 0) {
        std::fprintf(stderr,
                     "cluster_scene: --cluster-triangles %u is not a multiple of 4 (meshoptimizer "
                     "needs it)\n",
                     c.clusterTriangles);
        return 1;
    }
    try {
        return run(c);
    } catch (const MissingExtension& e) {
        std::fprintf(stderr, "cluster_scene: %s\n", e.what());
        return kExitNoExtension;
    } catch (const std::exception& e) {
        std::fprintf(stderr, "cluster_scene: %s\n", e.what());
        return kExitFailure;
    }
}
