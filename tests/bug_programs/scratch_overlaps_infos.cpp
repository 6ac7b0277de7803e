// SPDX-License-Identifier: Apache-2.0
// Bug: the engine sub-allocates one big buffer (an arena: src infos, count, addresses, scratch,
// CLAS, each at an offset of its own, 256-byte aligned) and reaches every part by the arena's
// device address plus its offset. Its offset arithmetic takes the src infos' part as one
// info's size, not count infos': the scratch starts 256 bytes into the arena, inside the src
// infos the same command reads (8 infos of 64 bytes: the scratch begins at info 4).
// --fixed sizes the part count infos.
#include "bug_gpu.h"

using namespace bug_programs;

namespace {

constexpr VkDeviceSize kPartAlignment = 256;

struct Arena {
    Buffer memory;
    VkDeviceSize used = 0;
    VkDeviceAddress take(VkDeviceSize size) {
        const VkDeviceSize at = align_up(used, kPartAlignment);
        used = at + size;
        if (used > memory.size) die("the arena is full");
        return memory.address + at;
    }
    unsigned char* host(VkDeviceAddress address) {
        return memory.host + (address - memory.address);
    }
};

}  // namespace

int main(int argc, char** argv) {
    const bool fixed = has_flag(argc, argv, "--fixed");
    Gpu gpu;
    open(gpu, "scratch_overlaps_infos");
    const Quads quads = make_quads(gpu, 8);
    ClasBuild clas;
    prepare_clas_build(gpu, quads, clas);  // the sizes and the infos the engine computes
    const VkDeviceSize infos_size = clas.info.srcInfosArray.size;
    const VkDeviceSize one_info = clas.info.srcInfosArray.stride;
    Arena arena{gpu.buffer(infos_size + clas.scratch.size + clas.objects.size + 4096)};

    const VkDeviceAddress infos = arena.take(infos_size);
    arena.used = (infos - arena.memory.address) + (fixed ? infos_size : one_info);
    const VkDeviceAddress scratch = arena.take(clas.scratch.size);
    const VkDeviceAddress count = arena.take(sizeof(uint32_t));
    const VkDeviceAddress addresses = arena.take(clas.addresses.size);
    const VkDeviceAddress objects = arena.take(clas.objects.size);
    std::memcpy(arena.host(infos), clas.infos.host, infos_size);
    std::memcpy(arena.host(count), &quads.count, sizeof quads.count);
    clas.info.srcInfosArray.deviceAddress = infos;
    clas.info.srcInfosCount = count;
    clas.info.scratchData = scratch;
    clas.info.dstAddressesArray.deviceAddress = addresses;
    clas.info.dstImplicitData = objects;

    VkCommandBuffer cb = gpu.begin();
    gpu.cmd_build_clusters(cb, &clas.info);
    gpu.submit_and_wait(cb);
    print_range("infos", infos, infos_size);
    print_range("scratch", scratch, clas.scratch.size);
    return 0;
}
