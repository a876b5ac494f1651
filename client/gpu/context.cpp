#include "context.h"

#include "sanitizers.h"

#if defined(SURFCAST_ASAN)
#include <dlfcn.h>
#endif

#include <cstdio>
#include <cstring>

#include "vk_check.h"

namespace surfcast::gpu {

const char* vkResultName(VkResult r) {
    switch (r) {
#define NAME(x) case x: return #x;
        NAME(VK_SUCCESS) NAME(VK_NOT_READY) NAME(VK_TIMEOUT) NAME(VK_INCOMPLETE) NAME(VK_SUBOPTIMAL_KHR)
        NAME(VK_ERROR_OUT_OF_HOST_MEMORY) NAME(VK_ERROR_OUT_OF_DEVICE_MEMORY) NAME(VK_ERROR_INITIALIZATION_FAILED)
        NAME(VK_ERROR_DEVICE_LOST) NAME(VK_ERROR_MEMORY_MAP_FAILED) NAME(VK_ERROR_LAYER_NOT_PRESENT)
        NAME(VK_ERROR_EXTENSION_NOT_PRESENT) NAME(VK_ERROR_FEATURE_NOT_PRESENT) NAME(VK_ERROR_INCOMPATIBLE_DRIVER)
        NAME(VK_ERROR_TOO_MANY_OBJECTS) NAME(VK_ERROR_FORMAT_NOT_SUPPORTED) NAME(VK_ERROR_SURFACE_LOST_KHR)
        NAME(VK_ERROR_NATIVE_WINDOW_IN_USE_KHR) NAME(VK_ERROR_OUT_OF_DATE_KHR)
#undef NAME
    default: return "VkResult(other)";
    }
}

Status vkError(const char* call, VkResult result, const char* file, int line) {
    return Status::error(std::string("Vulkan: ") + call + " failed with " + vkResultName(result) + " (" + file + ":" +
                         std::to_string(line) + ")");
}

namespace {
// AddressSanitizer builds only (scripts/sanitize.sh): Mesa's lavapipe is
// dlclose()d with the last Vulkan instance, and LeakSanitizer then reports
// what the driver's own globals still pointed to (240 bytes per process,
// stacks ending in "<unknown module>"): third-party, not a leak of ours, and
// not matchable by a suppression. Keeping the driver loaded for the process
// keeps those pointers visible and hides nothing of ours.
void keepDriverLoaded() {
#if defined(SURFCAST_ASAN)
    static void* pinned = dlopen("libvulkan_lvp.so", RTLD_NOW | RTLD_NODELETE);
    (void)pinned;
#endif
}

VKAPI_ATTR VkBool32 VKAPI_CALL onValidationMessage(VkDebugUtilsMessageSeverityFlagBitsEXT severity,
                                                   VkDebugUtilsMessageTypeFlagsEXT, const VkDebugUtilsMessengerCallbackDataEXT* data,
                                                   void* user) {
    auto* ctx = static_cast<Context*>(user);
    bool error = severity & VK_DEBUG_UTILS_MESSAGE_SEVERITY_ERROR_BIT_EXT;
    (error ? ctx->validationErrors : ctx->validationWarnings)++;
    std::fprintf(stderr, "vulkan validation %s: %s\n", error ? "error" : "warning", data->pMessage);
    return VK_FALSE;
}

int typeRank(VkPhysicalDeviceType type) {
    switch (type) {
    case VK_PHYSICAL_DEVICE_TYPE_DISCRETE_GPU: return 0;
    case VK_PHYSICAL_DEVICE_TYPE_INTEGRATED_GPU: return 1;
    case VK_PHYSICAL_DEVICE_TYPE_VIRTUAL_GPU: return 2;
    case VK_PHYSICAL_DEVICE_TYPE_CPU: return 3;
    default: return 4;
    }
}

const char* typeName(VkPhysicalDeviceType type) {
    switch (type) {
    case VK_PHYSICAL_DEVICE_TYPE_DISCRETE_GPU: return "discrete GPU";
    case VK_PHYSICAL_DEVICE_TYPE_INTEGRATED_GPU: return "integrated GPU";
    case VK_PHYSICAL_DEVICE_TYPE_VIRTUAL_GPU: return "virtual GPU";
    case VK_PHYSICAL_DEVICE_TYPE_CPU: return "CPU";
    default: return "other";
    }
}

Result<VkInstance> createInstance(const ContextOptions& options, bool* debugUtils) {
    keepDriverLoaded();
    VkApplicationInfo app{VK_STRUCTURE_TYPE_APPLICATION_INFO};
    app.pApplicationName = "surfcast";
    app.apiVersion = VK_API_VERSION_1_3;
    std::vector<const char*> layers, extensions;
    for (const auto& e : options.instanceExtensions) extensions.push_back(e.c_str());
    *debugUtils = false;
    if (options.validation) {
        uint32_t count = 0;
        vkEnumerateInstanceLayerProperties(&count, nullptr);
        std::vector<VkLayerProperties> available(count);
        vkEnumerateInstanceLayerProperties(&count, available.data());
        bool found = false;
        for (const auto& l : available) found = found || std::strcmp(l.layerName, "VK_LAYER_KHRONOS_validation") == 0;
        if (!found)
            return Status::error("Vulkan validation was requested but VK_LAYER_KHRONOS_validation is not installed "
                                 "(Debian: vulkan-validationlayers)");
        layers.push_back("VK_LAYER_KHRONOS_validation");
        extensions.push_back(VK_EXT_DEBUG_UTILS_EXTENSION_NAME);
        *debugUtils = true;
    }
    VkInstanceCreateInfo info{VK_STRUCTURE_TYPE_INSTANCE_CREATE_INFO};
    info.pApplicationInfo = &app;
    info.enabledLayerCount = uint32_t(layers.size());
    info.ppEnabledLayerNames = layers.data();
    info.enabledExtensionCount = uint32_t(extensions.size());
    info.ppEnabledExtensionNames = extensions.data();
    VkInstance instance = VK_NULL_HANDLE;
    VkResult r = vkCreateInstance(&info, nullptr, &instance);
    if (r == VK_ERROR_INCOMPATIBLE_DRIVER || r == VK_ERROR_INITIALIZATION_FAILED)
        return Status::error(std::string("no Vulkan 1.3 driver found (") + vkResultName(r) +
                             "); install one, e.g. Debian's mesa-vulkan-drivers for lavapipe");
    VK_TRY(r);
    return instance;
}

std::vector<VkPhysicalDevice> physicalDevices(VkInstance instance) {
    uint32_t count = 0;
    vkEnumeratePhysicalDevices(instance, &count, nullptr);
    std::vector<VkPhysicalDevice> devices(count);
    vkEnumeratePhysicalDevices(instance, &count, devices.data());
    return devices;
}

// Why a device cannot run Surfcast, or "" when it can.
std::string unsuitable(VkPhysicalDevice device, uint32_t* family) {
    VkPhysicalDeviceProperties props;
    vkGetPhysicalDeviceProperties(device, &props);
    if (props.apiVersion < VK_API_VERSION_1_3) return "Vulkan 1.3 needed";
    VkPhysicalDeviceVulkan13Features f13{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_1_3_FEATURES};
    VkPhysicalDeviceFeatures2 features{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_FEATURES_2, &f13};
    vkGetPhysicalDeviceFeatures2(device, &features);
    if (!f13.dynamicRendering || !f13.synchronization2) return "dynamic rendering and synchronization2 needed";
    uint32_t count = 0;
    vkGetPhysicalDeviceQueueFamilyProperties(device, &count, nullptr);
    std::vector<VkQueueFamilyProperties> families(count);
    vkGetPhysicalDeviceQueueFamilyProperties(device, &count, families.data());
    for (uint32_t i = 0; i < count; ++i)
        if (families[i].queueFlags & VK_QUEUE_GRAPHICS_BIT) {
            *family = i;
            return "";
        }
    return "no graphics queue";
}

}  // namespace

std::string listDevices() {
    ContextOptions options;
    bool debug = false;
    auto instance = createInstance(options, &debug);
    if (!instance) return instance.status().message() + "\n";
    std::string out;
    auto devices = physicalDevices(*instance);
    for (size_t i = 0; i < devices.size(); ++i) {
        VkPhysicalDeviceProperties props;
        vkGetPhysicalDeviceProperties(devices[i], &props);
        uint32_t family;
        std::string why = unsuitable(devices[i], &family);
        out += std::to_string(i) + ": " + props.deviceName + " (" + typeName(props.deviceType) + ")" +
               (why.empty() ? "" : " unusable: " + why) + "\n";
    }
    vkDestroyInstance(*instance, nullptr);
    return out;
}

namespace {
// Timestamp support and the command pool, for a device made here or by the host.
Status finishContext(Context& ctx) {
    uint32_t count = 0;
    vkGetPhysicalDeviceQueueFamilyProperties(ctx.physicalDevice, &count, nullptr);
    std::vector<VkQueueFamilyProperties> families(count);
    vkGetPhysicalDeviceQueueFamilyProperties(ctx.physicalDevice, &count, families.data());
    if (ctx.queueFamily >= count) return Status::error("queue family " + std::to_string(ctx.queueFamily) + " does not exist");
    ctx.timestamps = families[ctx.queueFamily].timestampValidBits > 0 && ctx.properties.limits.timestampPeriod > 0;
    VkCommandPoolCreateInfo pool{VK_STRUCTURE_TYPE_COMMAND_POOL_CREATE_INFO};
    pool.flags = VK_COMMAND_POOL_CREATE_RESET_COMMAND_BUFFER_BIT;
    pool.queueFamilyIndex = ctx.queueFamily;
    if (VkResult r = vkCreateCommandPool(ctx.device, &pool, nullptr, &ctx.commandPool); r != VK_SUCCESS)
        return vkError("vkCreateCommandPool", r, __FILE__, __LINE__);
    return {};
}
}  // namespace

Result<std::unique_ptr<Context>> createContext(const ContextOptions& options) {
    auto ctx = std::make_unique<Context>();
    bool debugUtils = false;
    auto instance = createInstance(options, &debugUtils);
    if (!instance) return instance.status();
    ctx->instance = *instance;
    // From here on a failure must release what exists.
    auto fail = [&](Status s) -> Result<std::unique_ptr<Context>> {
        destroyContext(ctx);
        return s;
    };
    if (debugUtils) {
        VkDebugUtilsMessengerCreateInfoEXT info{VK_STRUCTURE_TYPE_DEBUG_UTILS_MESSENGER_CREATE_INFO_EXT};
        info.messageSeverity = VK_DEBUG_UTILS_MESSAGE_SEVERITY_WARNING_BIT_EXT | VK_DEBUG_UTILS_MESSAGE_SEVERITY_ERROR_BIT_EXT;
        // Performance hints are left out: they flag by-design choices (outputs
        // a specialization does not consume) and would bury real messages.
        info.messageType = VK_DEBUG_UTILS_MESSAGE_TYPE_GENERAL_BIT_EXT | VK_DEBUG_UTILS_MESSAGE_TYPE_VALIDATION_BIT_EXT;
        info.pfnUserCallback = onValidationMessage;
        info.pUserData = ctx.get();
        auto create = reinterpret_cast<PFN_vkCreateDebugUtilsMessengerEXT>(
            vkGetInstanceProcAddr(ctx->instance, "vkCreateDebugUtilsMessengerEXT"));
        if (create) create(ctx->instance, &info, nullptr, &ctx->messenger);
    }

    auto devices = physicalDevices(ctx->instance);
    if (devices.empty()) return fail(Status::error("Vulkan reports no devices; install a driver (e.g. mesa-vulkan-drivers)"));
    int chosen = -1, bestRank = 1 << 30;
    std::string reasons;
    for (size_t i = 0; i < devices.size(); ++i) {
        VkPhysicalDeviceProperties props;
        vkGetPhysicalDeviceProperties(devices[i], &props);
        bool named = options.device.empty() || options.device == std::to_string(i) ||
                     std::strstr(props.deviceName, options.device.c_str()) != nullptr;
        if (!named) continue;
        uint32_t family = 0;
        std::string why = unsuitable(devices[i], &family);
        if (!why.empty()) {
            reasons += std::string(" ") + props.deviceName + ": " + why + ";";
            continue;
        }
        int rank = typeRank(props.deviceType);
        if (rank < bestRank) {
            bestRank = rank;
            chosen = int(i);
            ctx->queueFamily = family;
        }
    }
    if (chosen < 0)
        return fail(Status::error("no usable Vulkan device" +
                                  (options.device.empty() ? std::string() : " matching --device '" + options.device + "'") +
                                  "." + reasons + " Devices:\n" + listDevices()));
    ctx->physicalDevice = devices[size_t(chosen)];
    vkGetPhysicalDeviceProperties(ctx->physicalDevice, &ctx->properties);

    VkPhysicalDeviceFeatures supported;
    vkGetPhysicalDeviceFeatures(ctx->physicalDevice, &supported);
    ctx->geometryShader = supported.geometryShader;
    VkPhysicalDeviceVulkan13Features f13{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_1_3_FEATURES};
    f13.dynamicRendering = VK_TRUE;
    f13.synchronization2 = VK_TRUE;
    VkPhysicalDeviceFeatures2 features{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_FEATURES_2, &f13};
    features.features.geometryShader = supported.geometryShader;
    float priority = 1.f;
    VkDeviceQueueCreateInfo queue{VK_STRUCTURE_TYPE_DEVICE_QUEUE_CREATE_INFO};
    queue.queueFamilyIndex = ctx->queueFamily;
    queue.queueCount = 1;
    queue.pQueuePriorities = &priority;
    const char* swapchainExtension = VK_KHR_SWAPCHAIN_EXTENSION_NAME;
    VkDeviceCreateInfo info{VK_STRUCTURE_TYPE_DEVICE_CREATE_INFO, &features};
    info.queueCreateInfoCount = 1;
    info.pQueueCreateInfos = &queue;
    info.enabledExtensionCount = options.swapchain ? 1 : 0;
    info.ppEnabledExtensionNames = &swapchainExtension;
    if (VkResult r = vkCreateDevice(ctx->physicalDevice, &info, nullptr, &ctx->device); r != VK_SUCCESS)
        return fail(vkError("vkCreateDevice", r, __FILE__, __LINE__));
    vkGetDeviceQueue(ctx->device, ctx->queueFamily, 0, &ctx->queue);

    if (Status st = finishContext(*ctx); !st) return fail(st);
    return ctx;
}

Result<std::unique_ptr<Context>> wrapContext(const HostDevice& host) {
    keepDriverLoaded();
    if (!host.instance || !host.physicalDevice || !host.device || !host.queue)
        return Status::error("wrapContext: the host device needs an instance, physical device, device and queue");
    auto ctx = std::make_unique<Context>();
    ctx->ownsDevice = false;
    ctx->instance = host.instance;
    ctx->physicalDevice = host.physicalDevice;
    ctx->device = host.device;
    ctx->queueFamily = host.queueFamily;
    ctx->queue = host.queue;
    ctx->geometryShader = host.geometryShaderEnabled;
    vkGetPhysicalDeviceProperties(ctx->physicalDevice, &ctx->properties);
    if (Status st = finishContext(*ctx); !st) {
        destroyContext(ctx);
        return st;
    }
    return ctx;
}

void destroyContext(std::unique_ptr<Context>& ctx) {
    if (!ctx) return;
    if (ctx->device) {
        vkDeviceWaitIdle(ctx->device);
        if (ctx->commandPool) vkDestroyCommandPool(ctx->device, ctx->commandPool, nullptr);
        if (ctx->ownsDevice) vkDestroyDevice(ctx->device, nullptr);
    }
    if (!ctx->ownsDevice) {
        ctx.reset();
        return;
    }
    if (ctx->messenger) {
        auto destroy = reinterpret_cast<PFN_vkDestroyDebugUtilsMessengerEXT>(
            vkGetInstanceProcAddr(ctx->instance, "vkDestroyDebugUtilsMessengerEXT"));
        if (destroy) destroy(ctx->instance, ctx->messenger, nullptr);
    }
    if (ctx->instance) vkDestroyInstance(ctx->instance, nullptr);
    ctx.reset();
}

Status submitAndWaitImpl(Context& ctx, void (*record)(VkCommandBuffer, void*), void* user) {
    VkCommandBufferAllocateInfo alloc{VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO};
    alloc.commandPool = ctx.commandPool;
    alloc.level = VK_COMMAND_BUFFER_LEVEL_PRIMARY;
    alloc.commandBufferCount = 1;
    VkCommandBuffer cmd = VK_NULL_HANDLE;
    VK_TRY(vkAllocateCommandBuffers(ctx.device, &alloc, &cmd));
    VkCommandBufferBeginInfo begin{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO};
    begin.flags = VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
    VkFence fence = VK_NULL_HANDLE;
    VkFenceCreateInfo fenceInfo{VK_STRUCTURE_TYPE_FENCE_CREATE_INFO};
    VkResult r = vkBeginCommandBuffer(cmd, &begin);
    if (r == VK_SUCCESS) {
        record(cmd, user);
        r = vkEndCommandBuffer(cmd);
    }
    if (r == VK_SUCCESS) r = vkCreateFence(ctx.device, &fenceInfo, nullptr, &fence);
    if (r == VK_SUCCESS) {
        VkSubmitInfo submit{VK_STRUCTURE_TYPE_SUBMIT_INFO};
        submit.commandBufferCount = 1;
        submit.pCommandBuffers = &cmd;
        r = vkQueueSubmit(ctx.queue, 1, &submit, fence);
    }
    if (r == VK_SUCCESS) r = vkWaitForFences(ctx.device, 1, &fence, VK_TRUE, UINT64_MAX);
    if (fence) vkDestroyFence(ctx.device, fence, nullptr);
    vkFreeCommandBuffers(ctx.device, ctx.commandPool, 1, &cmd);
    VK_TRY(r);
    return {};
}

}  // namespace surfcast::gpu
