// SPDX-License-Identifier: Apache-2.0
// Bug: the engine keeps each CLAS address in a 16-byte record (the address, then the
// cluster's LOD word), so the cluster build's dstAddressesArray and the bottom level's
// clusterReferences have a stride of 16. Between the two builds, one vkCmdPipelineBarrier2 with
// two VkBufferMemoryBarrier2 (BUILD/AS_WRITE -> BUILD/AS_READ): the CLAS objects' buffer whole,
// and the records' buffer over count * sizeof(VkDeviceAddress) bytes, the size of a packed
// array. With 4 clusters the barrier covers records 0 and 1 only; the bottom level may read
// records 2 and 3 before the cluster build wrote them. --fixed: the records' size VK_WHOLE_SIZE.
#include "bug_gpu.h"

using namespace bug_programs;

namespace {

constexpr VkDeviceSize kRecord = 16;

VkBufferMemoryBarrier2 build_to_build(VkBuffer buffer, VkDeviceSize size) {
    VkBufferMemoryBarrier2 b{VK_STRUCTURE_TYPE_BUFFER_MEMORY_BARRIER_2};
    b.srcStageMask = b.dstStageMask = VK_PIPELINE_STAGE_2_ACCELERATION_STRUCTURE_BUILD_BIT_KHR;
    b.srcAccessMask = VK_ACCESS_2_ACCELERATION_STRUCTURE_WRITE_BIT_KHR;
    b.dstAccessMask = VK_ACCESS_2_ACCELERATION_STRUCTURE_READ_BIT_KHR;
    b.srcQueueFamilyIndex = b.dstQueueFamilyIndex = VK_QUEUE_FAMILY_IGNORED;
    b.buffer = buffer;
    b.size = size;
    return b;
}

// The records: 16 bytes each, the address first (the cluster build writes it), then a word
// the engine keeps for itself.
void use_records(Gpu& gpu, ClasBuild& clas, BlasBuild& blas, uint32_t count) {
    clas.addresses = gpu.buffer(kRecord * count);
    clas.info.dstAddressesArray = {clas.addresses.address, kRecord, kRecord * count};
    VkClusterAccelerationStructureBuildClustersBottomLevelInfoNV one{};
    one.clusterReferencesCount = count;
    one.clusterReferencesStride = kRecord;
    one.clusterReferences = clas.addresses.address;
    std::memcpy(blas.infos.host, &one, sizeof one);
}

}  // namespace

int main(int argc, char** argv) {
    const bool fixed = has_flag(argc, argv, "--fixed");
    Gpu gpu;
    open(gpu, "strided_addresses_barrier_short");
    const Quads quads = make_quads(gpu, 4);
    ClasBuild clas;
    prepare_clas_build(gpu, quads, clas);
    BlasBuild blas;
    prepare_blas_build(gpu, clas, quads.count, blas);
    use_records(gpu, clas, blas, quads.count);
    const VkDeviceSize packed = sizeof(VkDeviceAddress) * quads.count;

    VkCommandBuffer cb = gpu.begin();
    gpu.cmd_build_clusters(cb, &clas.info);
    const VkBufferMemoryBarrier2 barriers[2] = {build_to_build(clas.objects.buffer, VK_WHOLE_SIZE),
                                                build_to_build(clas.addresses.buffer,
                                                               fixed ? VK_WHOLE_SIZE : packed)};
    VkDependencyInfo dependency{VK_STRUCTURE_TYPE_DEPENDENCY_INFO};
    dependency.bufferMemoryBarrierCount = 2;
    dependency.pBufferMemoryBarriers = barriers;
    vkCmdPipelineBarrier2(cb, &dependency);
    gpu.cmd_build_clusters(cb, &blas.info);
    gpu.submit_and_wait(cb);
    print_range("records", clas.addresses.address, clas.addresses.size);
    print_range("uncovered", clas.addresses.address + packed, clas.addresses.size - packed);
    return 0;
}
