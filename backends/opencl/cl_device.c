/* OpenCL devices: enumeration, sub-devices, contexts, program builds and
 * error reporting.
 *
 * Device numbering: for each platform in ICD order, for each of its root
 * devices, the whole device first and then, where the device can be split
 * into one-compute-unit parts (CL_DEVICE_PARTITION_EQUALLY), each part.
 * On a two-core PoCL machine that is 0 = both cores, 1 and 2 = one core
 * each, which is what the scheduler needs to run two independent workers
 * on the CPU and to learn a cost model for each. rp_device_desc's
 * compute_units instead splits a root device equally into parts of that
 * many compute units and opens the first. */
#include <ctype.h>
#include <stdio.h>
#include <string.h>

#include "cl_internal.h"

/* PoCL sets its devices up on the first query (rp__driver_setup_*). */
static cl_int platform_ids(cl_uint max, cl_platform_id *plats, cl_uint *n) {
  cl_int err;
  rp__driver_setup_begin();
  err = clGetPlatformIDs(max, plats, n);
  rp__driver_setup_end();
  return err;
}

static cl_int device_ids(cl_platform_id plat, cl_uint max, cl_device_id *devs,
                         cl_uint *n) {
  cl_int err;
  rp__driver_setup_begin();
  err = clGetDeviceIDs(plat, CL_DEVICE_TYPE_ALL, max, devs, n);
  rp__driver_setup_end();
  return err;
}

#define RP_CL_MAX_PLATFORMS 16
#define RP_CL_MAX_DEVICES 64
/* The part of a build log quoted in rp_last_error; the full log is too
 * long for its buffer and mostly repeats the source. */
#define RP_CL_LOG_QUOTE 300

const char *rp_cl__error_name(cl_int err) {
  switch (err) {
#define RP_CL_ERR(name) case name: return #name;
    RP_CL_ERR(CL_SUCCESS)
    RP_CL_ERR(CL_DEVICE_NOT_FOUND)
    RP_CL_ERR(CL_DEVICE_NOT_AVAILABLE)
    RP_CL_ERR(CL_COMPILER_NOT_AVAILABLE)
    RP_CL_ERR(CL_MEM_OBJECT_ALLOCATION_FAILURE)
    RP_CL_ERR(CL_OUT_OF_RESOURCES)
    RP_CL_ERR(CL_OUT_OF_HOST_MEMORY)
    RP_CL_ERR(CL_PROFILING_INFO_NOT_AVAILABLE)
    RP_CL_ERR(CL_MEM_COPY_OVERLAP)
    RP_CL_ERR(CL_BUILD_PROGRAM_FAILURE)
    RP_CL_ERR(CL_MAP_FAILURE)
    RP_CL_ERR(CL_MISALIGNED_SUB_BUFFER_OFFSET)
    RP_CL_ERR(CL_EXEC_STATUS_ERROR_FOR_EVENTS_IN_WAIT_LIST)
    RP_CL_ERR(CL_COMPILE_PROGRAM_FAILURE)
    RP_CL_ERR(CL_LINKER_NOT_AVAILABLE)
    RP_CL_ERR(CL_LINK_PROGRAM_FAILURE)
    RP_CL_ERR(CL_DEVICE_PARTITION_FAILED)
    RP_CL_ERR(CL_INVALID_VALUE)
    RP_CL_ERR(CL_INVALID_DEVICE_TYPE)
    RP_CL_ERR(CL_INVALID_PLATFORM)
    RP_CL_ERR(CL_INVALID_DEVICE)
    RP_CL_ERR(CL_INVALID_CONTEXT)
    RP_CL_ERR(CL_INVALID_QUEUE_PROPERTIES)
    RP_CL_ERR(CL_INVALID_COMMAND_QUEUE)
    RP_CL_ERR(CL_INVALID_HOST_PTR)
    RP_CL_ERR(CL_INVALID_MEM_OBJECT)
    RP_CL_ERR(CL_INVALID_BINARY)
    RP_CL_ERR(CL_INVALID_BUILD_OPTIONS)
    RP_CL_ERR(CL_INVALID_PROGRAM)
    RP_CL_ERR(CL_INVALID_PROGRAM_EXECUTABLE)
    RP_CL_ERR(CL_INVALID_KERNEL_NAME)
    RP_CL_ERR(CL_INVALID_KERNEL_DEFINITION)
    RP_CL_ERR(CL_INVALID_KERNEL)
    RP_CL_ERR(CL_INVALID_ARG_INDEX)
    RP_CL_ERR(CL_INVALID_ARG_VALUE)
    RP_CL_ERR(CL_INVALID_ARG_SIZE)
    RP_CL_ERR(CL_INVALID_KERNEL_ARGS)
    RP_CL_ERR(CL_INVALID_WORK_DIMENSION)
    RP_CL_ERR(CL_INVALID_WORK_GROUP_SIZE)
    RP_CL_ERR(CL_INVALID_WORK_ITEM_SIZE)
    RP_CL_ERR(CL_INVALID_GLOBAL_OFFSET)
    RP_CL_ERR(CL_INVALID_EVENT_WAIT_LIST)
    RP_CL_ERR(CL_INVALID_EVENT)
    RP_CL_ERR(CL_INVALID_OPERATION)
    RP_CL_ERR(CL_INVALID_BUFFER_SIZE)
    RP_CL_ERR(CL_INVALID_GLOBAL_WORK_SIZE)
    RP_CL_ERR(CL_INVALID_PROPERTY)
    RP_CL_ERR(CL_INVALID_DEVICE_PARTITION_COUNT)
#undef RP_CL_ERR
  case -1001:
    return "CL_PLATFORM_NOT_FOUND_KHR";
  default:
    return "CL_UNKNOWN_ERROR";
  }
}

int rp_cl__fail(rp_context *ctx, cl_int err, const char *op) {
  /* A buffer the device cannot hold is the caller's memory problem, not
   * a broken device: the scheduler reacts to the two differently. Buffer
   * sizes are never 0 here, so CL_INVALID_BUFFER_SIZE means "larger than
   * the device's largest allocation". */
  int code = err == CL_MEM_OBJECT_ALLOCATION_FAILURE ||
                     err == CL_OUT_OF_RESOURCES ||
                     err == CL_OUT_OF_HOST_MEMORY ||
                     err == CL_INVALID_BUFFER_SIZE
                 ? RP_ENOMEM
                 : RP_EDEVICE;
  return rp__fail(ctx, code, "opencl: %s: %s (%d)", op,
                  rp_cl__error_name(err), (int)err);
}

/* ---- enumeration --------------------------------------------------------- */

/* Number of one-compute-unit parts `dev` splits into; 0 when it cannot
 * be split or would split into one part (which adds nothing). Asking for
 * the count alone creates no sub-devices. */
static cl_uint sub_device_count(cl_device_id dev) {
  const cl_device_partition_property props[] = {CL_DEVICE_PARTITION_EQUALLY,
                                                1, 0};
  cl_uint n = 0;
  if (clCreateSubDevices(dev, props, 0, NULL, &n) != CL_SUCCESS || n < 2)
    return 0;
  return n;
}

/* Where list entry `index` lives: its root device and which part of it
 * (-1: the whole device). Returns 0, or 1 when index is past the end. */
static int locate(uint32_t index, uint32_t *count, cl_device_id *root,
                  int *part) {
  cl_platform_id plats[RP_CL_MAX_PLATFORMS];
  cl_uint np = 0, p;
  uint32_t seen = 0;
  /* No ICD, or one with no platform: both are "no device", not errors. */
  if (platform_ids(RP_CL_MAX_PLATFORMS, plats, &np) != CL_SUCCESS)
    np = 0;
  if (np > RP_CL_MAX_PLATFORMS)
    np = RP_CL_MAX_PLATFORMS;
  for (p = 0; p < np; p++) {
    cl_device_id devs[RP_CL_MAX_DEVICES];
    cl_uint nd = 0, d;
    if (device_ids(plats[p], RP_CL_MAX_DEVICES, devs, &nd) != CL_SUCCESS)
      continue;
    if (nd > RP_CL_MAX_DEVICES)
      nd = RP_CL_MAX_DEVICES;
    for (d = 0; d < nd; d++) {
      cl_uint subs = sub_device_count(devs[d]);
      if (root != NULL && index == seen) {
        *root = devs[d];
        *part = -1;
        return 0;
      }
      if (root != NULL && index > seen && index - seen <= subs) {
        *root = devs[d];
        *part = (int)(index - seen - 1);
        return 0;
      }
      seen += 1 + subs;
    }
  }
  if (count != NULL)
    *count = seen;
  return 1;
}

int rp_cl__count_devices(uint32_t *count) {
  locate(0, count, NULL, NULL);
  return 0;
}

/* ---- open and close ------------------------------------------------------ */

int rp_cl__partition_units(rp_context *ctx, uint32_t index,
                           uint32_t *units) {
  cl_device_partition_property props[8];
  cl_device_id root = NULL;
  cl_uint have = 0;
  size_t size = 0, i;
  uint32_t count = 0;
  int part = -1;
  if (locate(index, &count, &root, &part) != 0)
    return rp__fail(ctx, RP_ENODEV, "opencl: device %u does not exist "
                    "(%u found)", (unsigned)index, (unsigned)count);
  if (part >= 0)
    return rp__fail(ctx, RP_EUNSUPPORTED, "opencl: device %u is already a "
                    "sub-device; partition its root device instead",
                    (unsigned)index);
  if (clGetDeviceInfo(root, CL_DEVICE_PARTITION_PROPERTIES, sizeof props,
                      props, &size) != CL_SUCCESS)
    size = 0;
  for (i = 0; i < size / sizeof props[0]; i++)
    if (props[i] == CL_DEVICE_PARTITION_EQUALLY)
      break;
  if (i >= size / sizeof props[0])
    return rp__fail(ctx, RP_EUNSUPPORTED, "opencl: device %u cannot be "
                    "partitioned (CL_DEVICE_PARTITION_PROPERTIES lacks "
                    "CL_DEVICE_PARTITION_EQUALLY)", (unsigned)index);
  clGetDeviceInfo(root, CL_DEVICE_MAX_COMPUTE_UNITS, sizeof have, &have,
                  NULL);
  *units = have;
  return 0;
}

/* Part `part` of `root` split into sub-devices of `units` compute units
 * each; the other parts are released. */
static cl_int make_sub_device(cl_device_id root, cl_uint units, int part,
                              cl_device_id *out) {
  const cl_device_partition_property props[] = {
      CL_DEVICE_PARTITION_EQUALLY, (cl_device_partition_property)units, 0};
  cl_device_id subs[RP_CL_MAX_DEVICES];
  cl_uint n = 0, i;
  cl_int err = clCreateSubDevices(root, props, RP_CL_MAX_DEVICES, subs, &n);
  if (err != CL_SUCCESS)
    return err;
  if (n > RP_CL_MAX_DEVICES)
    n = RP_CL_MAX_DEVICES;
  *out = NULL;
  for (i = 0; i < n; i++) {
    if ((int)i == part)
      *out = subs[i];
    else
      clReleaseDevice(subs[i]);
  }
  return *out != NULL ? CL_SUCCESS : CL_DEVICE_PARTITION_FAILED;
}

static void fill_caps(const rp_cl_impl *impl, int part, rp_caps *caps) {
  char name[96] = "";
  cl_ulong mem = 0, alloc = 0;
  cl_uint units = 0;
  memset(caps, 0, sizeof *caps);
  snprintf(caps->backend, sizeof caps->backend, "opencl");
  clGetDeviceInfo(impl->device, CL_DEVICE_NAME, sizeof name - 1, name, NULL);
  name[sizeof name - 1] = '\0';
  clGetDeviceInfo(impl->device, CL_DEVICE_GLOBAL_MEM_SIZE, sizeof mem, &mem,
                  NULL);
  clGetDeviceInfo(impl->device, CL_DEVICE_MAX_MEM_ALLOC_SIZE, sizeof alloc,
                  &alloc, NULL);
  clGetDeviceInfo(impl->device, CL_DEVICE_MAX_COMPUTE_UNITS, sizeof units,
                  &units, NULL);
  if (part >= 0)
    snprintf(caps->device, sizeof caps->device, "%s (sub-device %d, %u "
             "compute unit%s)", name, part, (unsigned)units,
             units == 1 ? "" : "s");
  else
    snprintf(caps->device, sizeof caps->device, "%s", name);
  caps->effects =
      RP_EFFECT_SHADING | RP_EFFECT_ERT | RP_EFFECT_SKIP | RP_EFFECT_AO |
      RP_EFFECT_PREINT;
  caps->voxel_types = (1u << RP_U8) | (1u << RP_U16) | (1u << RP_F32);
  caps->global_mem_bytes = mem;
  caps->max_alloc_bytes = alloc;
  caps->compute_units = units;
  caps->sub_device = part >= 0;
}

int rp_cl__open(rp_cl_impl *impl, uint32_t index, uint32_t compute_units,
                rp_caps *caps) {
  rp_context *ctx = impl->ctx;
  cl_device_id root = NULL, devs[2];
  cl_uint ndev = 1, units = 1;
  int part = -1;
  cl_int err;
  uint32_t count = 0;
  if (locate(index, &count, &root, &part) != 0)
    return rp__fail(ctx, RP_ENODEV, "opencl: device %u does not exist "
                    "(%u found)", (unsigned)index, (unsigned)count);
  /* A partition asked for is the first of the root split equally. */
  if (compute_units > 0 && part < 0) {
    units = compute_units;
    part = 0;
  }
  if (part < 0) {
    impl->device = root;
    impl->root = NULL;
  } else {
    err = make_sub_device(root, units, part, &impl->device);
    if (err == CL_DEVICE_PARTITION_FAILED || err == CL_INVALID_VALUE)
      return rp__fail(ctx, RP_EUNSUPPORTED, "opencl: clCreateSubDevices "
                      "(CL_DEVICE_PARTITION_EQUALLY, %u compute units): %s "
                      "(%d)", (unsigned)units, rp_cl__error_name(err),
                      (int)err);
    if (err != CL_SUCCESS)
      return rp_cl__fail(ctx, err, "clCreateSubDevices");
    impl->root = root;
  }
  devs[0] = impl->device;
  /* PoCL asserts when a context holds a sub-device without its parent,
   * so a sub-device's context has both; kernels run on the part only. */
  if (impl->root != NULL)
    devs[ndev++] = impl->root;
  impl->context = clCreateContext(NULL, ndev, devs, NULL, NULL, &err);
  if (impl->context == NULL) {
    rp_cl__close(impl);
    return rp_cl__fail(ctx, err, "clCreateContext");
  }
  impl->queue = clCreateCommandQueue(impl->context, impl->device,
                                     CL_QUEUE_PROFILING_ENABLE, &err);
  if (impl->queue == NULL) {
    rp_cl__close(impl);
    return rp_cl__fail(ctx, err, "clCreateCommandQueue (profiling)");
  }
  fill_caps(impl, part, caps);
  return 0;
}

void rp_cl__close(rp_cl_impl *impl) {
  if (impl->queue != NULL)
    clReleaseCommandQueue(impl->queue);
  if (impl->context != NULL)
    clReleaseContext(impl->context);
  /* Root devices are not reference counted; sub-devices are. */
  if (impl->root != NULL && impl->device != NULL)
    clReleaseDevice(impl->device);
  impl->queue = NULL;
  impl->context = NULL;
  impl->device = NULL;
  impl->root = NULL;
}

/* ---- builds -------------------------------------------------------------- */

/* Copies the most useful part of a build log into out (size n): from the
 * first line that mentions "error" (the log often starts with warnings),
 * lines joined with " | ", cut with "..." when too long. */
static void quote_log(const char *log, char *out, size_t n) {
  const char *start = log, *p, *hit;
  size_t len = 0, cap = n - 4; /* room for "..." and the NUL */
  for (p = log; *p != '\0'; p = strchr(p, '\n') + 1) {
    const char *eol = strchr(p, '\n');
    hit = strstr(p, "error");
    if (hit != NULL && (eol == NULL || hit < eol)) {
      start = p;
      break;
    }
    if (eol == NULL)
      break;
  }
  for (p = start; *p != '\0' && len < cap; p++) {
    if (*p == '\n') {
      if (len + 3 > cap)
        break;
      memcpy(out + len, " | ", 3);
      len += 3;
    } else if (isprint((unsigned char)*p)) {
      out[len++] = *p;
    }
  }
  if (len >= 3 && memcmp(out + len - 3, " | ", 3) == 0)
    len -= 3;
  if (p[strspn(p, " \t\r\n")] != '\0') {
    memcpy(out + len, "...", 3);
    len += 3;
  }
  out[len] = '\0';
}

int rp_cl__build(rp_cl_impl *impl, rp_context *ctx, const char *what,
                 const char **sources, cl_uint count, const char *options,
                 cl_program *out) {
  cl_program prog;
  cl_int err;
  size_t log_size = 0;
  char *log, quote[RP_CL_LOG_QUOTE];
  prog = clCreateProgramWithSource(impl->context, count, sources, NULL, &err);
  if (prog == NULL)
    return rp_cl__fail(ctx, err, "clCreateProgramWithSource");
  err = clBuildProgram(prog, 1, &impl->device, options, NULL, NULL);
  if (err == CL_SUCCESS) {
    *out = prog;
    return 0;
  }
  if (err != CL_BUILD_PROGRAM_FAILURE && err != CL_INVALID_BUILD_OPTIONS) {
    clReleaseProgram(prog);
    return rp_cl__fail(ctx, err, "clBuildProgram");
  }
  quote[0] = '\0';
  if (clGetProgramBuildInfo(prog, impl->device, CL_PROGRAM_BUILD_LOG, 0,
                            NULL, &log_size) == CL_SUCCESS &&
      log_size > 0 && (log = rp__malloc(ctx, log_size + 1)) != NULL) {
    if (clGetProgramBuildInfo(prog, impl->device, CL_PROGRAM_BUILD_LOG,
                              log_size, log, NULL) == CL_SUCCESS) {
      log[log_size] = '\0';
      quote_log(log, quote, sizeof quote);
    }
    rp__free(ctx, log);
  }
  clReleaseProgram(prog);
  return rp__fail(ctx, RP_EBUILD, "opencl: building the %s kernel failed "
                  "(%s; options \"%.60s\"): %s", what,
                  rp_cl__error_name(err), options != NULL ? options : "",
                  quote[0] != '\0' ? quote : "(no build log)");
}
