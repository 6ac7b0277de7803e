// SPDX-License-Identifier: Apache-2.0
// The engine gives each streamed mesh a memory allocation of its own. Bug: after submitting the
// cluster build over a mesh, it frees the mesh's vertex memory at once (vkFreeMemory, no fence
// wait), as if the submission had copied what it needs: the build may still read it
// (VUID-vkFreeMemory-memory-00677). The buffer itself is destroyed after the wait. --fixed
// waits on the build's fence before freeing.
#include "bug_gpu.h"

using namespace bug_programs;

namespace {

// A buffer over a memory allocation of its own, which the Gpu helper does not own.
Buffer own_allocation(Gpu& gpu, VkDeviceSize size) {
    Buffer b = gpu.buffer(size);
    gpu.buffers.pop_back();  // freed and destroyed by the program, not the helper
    return b;
}

}  // namespace

int main(int argc, char** argv) {
    const bool fixed = has_flag(argc, argv, "--fixed");
    Gpu gpu;
    open(gpu, "memory_freed_in_flight");
    Quads quads = make_quads(gpu, 4);
    Buffer vertices = own_allocation(gpu, quads.vertices.size);
    std::memcpy(vertices.host, quads.vertices.host, quads.vertices.size);
    quads.vertices = vertices;
    ClasBuild clas;
    prepare_clas_build(gpu, quads, clas);

    VkCommandBuffer build = gpu.begin();
    gpu.cmd_build_clusters(build, &clas.info);
    VkFence built = gpu.fence();
    gpu.submit(build, built);
    if (fixed) gpu.wait(built);
    vkFreeMemory(gpu.device, vertices.memory, nullptr);  // the mesh is "uploaded": let it go
    if (!fixed) gpu.wait(built);
    vkDestroyBuffer(gpu.device, vertices.buffer, nullptr);
    print_range("vertices", vertices.address, vertices.size);
    return 0;
}
