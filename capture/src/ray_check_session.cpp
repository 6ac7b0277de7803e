// SPDX-License-Identifier: Apache-2.0
#include "ray_check_session.h"

namespace clastrace::capture::ray_check {

bool Session::load() {
#define CLASTRACE_LOAD(name)                                                         \
    f.name = (PFN_vk##name)context.get_device_proc_addr(context.device, "vk" #name); \
    if (!f.name) {                                                                   \
        error = "the device has no vk" #name;                                        \
        return false;                                                                \
    }
    CLASTRACE_TRACER_FUNCTIONS(CLASTRACE_LOAD)
#undef CLASTRACE_LOAD
#define CLASTRACE_LOAD_OPTIONAL(name) \
    f.name = (PFN_vk##name)context.get_device_proc_addr(context.device, "vk" #name);
    CLASTRACE_TRACER_OPTIONAL_FUNCTIONS(CLASTRACE_LOAD_OPTIONAL)
#undef CLASTRACE_LOAD_OPTIONAL
    return true;
}

bool Session::check(VkResult result, const char* what) {
    if (result == VK_SUCCESS) return true;
    error = std::string(what) + " failed with VkResult " + std::to_string(int(result));
    return false;
}

bool Session::host_buffer(VkDeviceSize size, VkBufferUsageFlags usage, HostBuffer& out) {
    out.size = size ? size : 16;
    VkBufferCreateInfo info{VK_STRUCTURE_TYPE_BUFFER_CREATE_INFO};
    info.size = out.size;
    info.usage = usage;
    info.sharingMode = VK_SHARING_MODE_EXCLUSIVE;
    if (!check(f.CreateBuffer(device(), &info, nullptr, &out.buffer), "vkCreateBuffer"))
        return false;
    VkBuffer buffer = out.buffer;
    cleanup.push_back([this, buffer] { f.DestroyBuffer(device(), buffer, nullptr); });
    VkMemoryRequirements requirements;
    f.GetBufferMemoryRequirements(device(), out.buffer, &requirements);
    const VkMemoryPropertyFlags wanted =
        VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT | VK_MEMORY_PROPERTY_HOST_COHERENT_BIT;
    uint32_t type = UINT32_MAX;
    for (uint32_t i = 0; i < context.memory_properties.memoryTypeCount && type == UINT32_MAX; ++i)
        if ((requirements.memoryTypeBits & (1u << i)) &&
            (context.memory_properties.memoryTypes[i].propertyFlags & wanted) == wanted)
            type = i;
    if (type == UINT32_MAX) {
        error = "no host-visible coherent memory type for the ray check's buffers";
        return false;
    }
    VkMemoryAllocateInfo allocate{VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO};
    allocate.allocationSize = requirements.size;
    allocate.memoryTypeIndex = type;
    if (!check(f.AllocateMemory(device(), &allocate, nullptr, &out.memory), "vkAllocateMemory"))
        return false;
    VkDeviceMemory memory = out.memory;
    cleanup.push_back([this, memory] { f.FreeMemory(device(), memory, nullptr); });  // unmaps too
    if (!check(f.BindBufferMemory(device(), out.buffer, out.memory, 0), "vkBindBufferMemory"))
        return false;
    if (!check(f.MapMemory(device(), out.memory, 0, VK_WHOLE_SIZE, 0, &out.mapped), "vkMapMemory"))
        return false;
    std::memset(out.mapped, 0, out.size);
    return true;
}

bool Session::shader(const uint32_t* code, size_t bytes, VkShaderModule& out) {
    VkShaderModuleCreateInfo info{VK_STRUCTURE_TYPE_SHADER_MODULE_CREATE_INFO};
    info.codeSize = bytes;
    info.pCode = code;
    if (!check(f.CreateShaderModule(device(), &info, nullptr, &out), "vkCreateShaderModule"))
        return false;
    VkShaderModule module = out;
    cleanup.push_back([this, module] { f.DestroyShaderModule(device(), module, nullptr); });
    return true;
}

bool create_ray_check_layout(Session& s, VkShaderStageFlags stages,
                             VkDescriptorType acceleration_structure_type,
                             uint32_t push_constant_bytes, RayCheckLayout& out) {
    VkDescriptorSetLayoutBinding bindings[6];
    for (uint32_t b = 0; b < 6; ++b)
        bindings[b] = {b, b == 0 ? acceleration_structure_type : VK_DESCRIPTOR_TYPE_STORAGE_BUFFER,
                       1, stages, nullptr};
    VkDescriptorSetLayoutCreateInfo set_info{VK_STRUCTURE_TYPE_DESCRIPTOR_SET_LAYOUT_CREATE_INFO};
    set_info.bindingCount = 6;
    set_info.pBindings = bindings;
    VkDescriptorSetLayout set_layout;
    if (!s.check(s.f.CreateDescriptorSetLayout(s.device(), &set_info, nullptr, &set_layout),
                 "vkCreateDescriptorSetLayout"))
        return false;
    s.cleanup.push_back(
        [&s, set_layout] { s.f.DestroyDescriptorSetLayout(s.device(), set_layout, nullptr); });
    out.set_layout = set_layout;
    VkPipelineLayoutCreateInfo layout_info{VK_STRUCTURE_TYPE_PIPELINE_LAYOUT_CREATE_INFO};
    layout_info.setLayoutCount = 1;
    layout_info.pSetLayouts = &set_layout;
    const VkPushConstantRange push_constants{stages, 0, push_constant_bytes};
    layout_info.pushConstantRangeCount = push_constant_bytes ? 1 : 0;
    layout_info.pPushConstantRanges = &push_constants;
    VkPipelineLayout pipeline_layout;
    if (!s.check(s.f.CreatePipelineLayout(s.device(), &layout_info, nullptr, &pipeline_layout),
                 "vkCreatePipelineLayout"))
        return false;
    s.cleanup.push_back(
        [&s, pipeline_layout] { s.f.DestroyPipelineLayout(s.device(), pipeline_layout, nullptr); });
    out.pipeline_layout = pipeline_layout;
    return true;
}


bool upload_ray_check_buffers(Session& s, const NvTraceScene& scene,
                              const std::vector<NvTracedRay>& rays, RayCheckBuffers& out) {
    std::vector<uint32_t> instance_info;
    for (const auto& i : scene.instances) {
        instance_info.push_back(i.sbt_record_offset);
        instance_info.push_back(i.first_geometry_slot);
    }
    std::vector<uint32_t> geometry_table;
    for (size_t g = 0; g < scene.geometry_is_aabb.size(); ++g)
        geometry_table.push_back(scene.geometry_is_aabb[g] && g < scene.geometry_first_box.size()
                                     ? scene.geometry_first_box[g]
                                     : 0xFFFFFFFFu);
    const VkBufferUsageFlags storage = VK_BUFFER_USAGE_STORAGE_BUFFER_BIT;
    return s.upload(rays, storage, out.rays) &&
           s.host_buffer(rays.size() * sizeof(NvRayHit), storage, out.hits) &&
           s.upload(instance_info, storage, out.instances) &&
           s.upload(geometry_table, storage, out.geometries) &&
           s.upload(scene.boxes, storage, out.boxes);
}


bool write_descriptor_set(Session& s, VkDescriptorSetLayout set_layout,
                          const TopLevelDescriptor& top_level, const RayCheckBuffers& buffers,
                          VkDescriptorSet& out) {
    VkDescriptorPoolSize pool_sizes[2] = {{top_level.type, 1},
                                          {VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, 5}};
    VkDescriptorPoolCreateInfo pool_info{VK_STRUCTURE_TYPE_DESCRIPTOR_POOL_CREATE_INFO};
    pool_info.maxSets = 1;
    pool_info.poolSizeCount = 2;
    pool_info.pPoolSizes = pool_sizes;
    VkDescriptorPool pool;
    if (!s.check(s.f.CreateDescriptorPool(s.device(), &pool_info, nullptr, &pool),
                 "vkCreateDescriptorPool"))
        return false;
    s.cleanup.push_back([&s, pool] { s.f.DestroyDescriptorPool(s.device(), pool, nullptr); });
    VkDescriptorSetAllocateInfo set_allocate{VK_STRUCTURE_TYPE_DESCRIPTOR_SET_ALLOCATE_INFO};
    set_allocate.descriptorPool = pool;
    set_allocate.descriptorSetCount = 1;
    set_allocate.pSetLayouts = &set_layout;
    VkDescriptorSet set;
    if (!s.check(s.f.AllocateDescriptorSets(s.device(), &set_allocate, &set),
                 "vkAllocateDescriptorSets"))
        return false;
    const HostBuffer* storage_buffers[5] = {&buffers.rays, &buffers.hits, &buffers.instances,
                                            &buffers.geometries, &buffers.boxes};
    VkDescriptorBufferInfo buffer_infos[5];
    VkWriteDescriptorSet writes[6] = {};
    writes[0] = {
        VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET, top_level.write, set, 0, 0, 1, top_level.type};
    for (uint32_t b = 0; b < 5; ++b) {
        buffer_infos[b] = {storage_buffers[b]->buffer, 0, VK_WHOLE_SIZE};
        writes[b + 1] = {VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET,
                         nullptr,
                         set,
                         b + 1,
                         0,
                         1,
                         VK_DESCRIPTOR_TYPE_STORAGE_BUFFER,
                         nullptr,
                         &buffer_infos[b],
                         nullptr};
    }
    s.f.UpdateDescriptorSets(s.device(), 6, writes, 0, nullptr);
    out = set;
    return true;
}


bool allocate_command_buffer(Session& s, VkCommandBuffer& out) {
    VkCommandPoolCreateInfo command_pool_info{VK_STRUCTURE_TYPE_COMMAND_POOL_CREATE_INFO};
    command_pool_info.flags = VK_COMMAND_POOL_CREATE_TRANSIENT_BIT;
    command_pool_info.queueFamilyIndex = s.context.queue_family_index;
    VkCommandPool command_pool;
    if (!s.check(s.f.CreateCommandPool(s.device(), &command_pool_info, nullptr, &command_pool),
                 "vkCreateCommandPool"))
        return false;
    s.cleanup.push_back(
        [&s, command_pool] { s.f.DestroyCommandPool(s.device(), command_pool, nullptr); });
    VkCommandBufferAllocateInfo cb_info{VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO};
    cb_info.commandPool = command_pool;
    cb_info.level = VK_COMMAND_BUFFER_LEVEL_PRIMARY;
    cb_info.commandBufferCount = 1;
    if (!s.check(s.f.AllocateCommandBuffers(s.device(), &cb_info, &out),
                 "vkAllocateCommandBuffers"))
        return false;
    if (s.context.set_command_buffer_dispatch)
        *reinterpret_cast<void**>(out) = *reinterpret_cast<void**>(s.device());
    return true;
}


bool record_ray_check(Session& s, VkCommandBuffer cb, VkPipelineBindPoint bind_point,
                      VkPipelineStageFlags stage, VkPipeline pipeline,
                      VkPipelineLayout pipeline_layout, VkDescriptorSet set,
                      const std::function<void()>& trace) {
    auto& f = s.f;
    VkCommandBufferBeginInfo begin{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO};
    begin.flags = VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
    if (!s.check(f.BeginCommandBuffer(cb, &begin), "vkBeginCommandBuffer")) return false;
    // Every earlier command of the queue (the builds) completes before the rays are traced.
    const VkMemoryBarrier before{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr,
                                 VK_ACCESS_MEMORY_WRITE_BIT,
                                 VK_ACCESS_ACCELERATION_STRUCTURE_READ_BIT_KHR |
                                     VK_ACCESS_SHADER_READ_BIT | VK_ACCESS_SHADER_WRITE_BIT};
    f.CmdPipelineBarrier(cb, VK_PIPELINE_STAGE_ALL_COMMANDS_BIT, stage, 0, 1, &before, 0, nullptr,
                         0, nullptr);
    f.CmdBindPipeline(cb, bind_point, pipeline);
    f.CmdBindDescriptorSets(cb, bind_point, pipeline_layout, 0, 1, &set, 0, nullptr);
    trace();
    const VkMemoryBarrier after{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr,
                                VK_ACCESS_SHADER_WRITE_BIT, VK_ACCESS_HOST_READ_BIT};
    f.CmdPipelineBarrier(cb, stage, VK_PIPELINE_STAGE_HOST_BIT, 0, 1, &after, 0, nullptr, 0,
                         nullptr);
    return s.check(f.EndCommandBuffer(cb), "vkEndCommandBuffer");
}

bool submit_and_wait(Session& s, VkCommandBuffer cb) {
    VkFenceCreateInfo fence_info{VK_STRUCTURE_TYPE_FENCE_CREATE_INFO};
    VkFence fence;
    if (!s.check(s.f.CreateFence(s.device(), &fence_info, nullptr, &fence), "vkCreateFence"))
        return false;
    s.cleanup.push_back([&s, fence] { s.f.DestroyFence(s.device(), fence, nullptr); });
    VkSubmitInfo submit{VK_STRUCTURE_TYPE_SUBMIT_INFO};
    submit.commandBufferCount = 1;
    submit.pCommandBuffers = &cb;
    if (!s.check(s.f.QueueSubmit(s.context.queue, 1, &submit, fence), "vkQueueSubmit"))
        return false;
    if (!s.check(s.f.WaitForFences(s.device(), 1, &fence, VK_TRUE, 10'000'000'000ull),
                 "vkWaitForFences")) {
        // The queue still owns our objects: leaking them beats freeing what the GPU may use.
        s.cleanup.clear();
        return false;
    }
    return true;
}

}  // namespace clastrace::capture::ray_check
