/* rp_device_desc's extension chain (raypace_testing.h): the testing
 * tier's structs, Vulkan pNext style. The front end checks the whole
 * chain before it opens anything, so that a host backend and the fault
 * wrapper can then look up their own struct without a check of their
 * own. */
#include <string.h>

#include "device.h"

const rp_ext_header *rp__ext_find(const void *next, rp_ext_type type) {
  const rp_ext_header *h;
  for (h = next; h != NULL; h = h->next)
    if (h->type == type)
      return h;
  return NULL;
}

int rp__ext_check(rp_context *ctx, const void *next, const char *name,
                  const rp_fault_desc **faults) {
  const rp_ext_header *h = next;
  uint32_t seen = 0, n;
  *faults = NULL;
  for (n = 0; h != NULL; h = h->next, n++) {
    uint32_t bit;
    if (h->type != RP_EXT_FAULTS && h->type != RP_EXT_TEST_BACKEND)
      return rp__fail(ctx, RP_EINVAL, "rp_device_create: extension struct "
                      "%u of desc->next has type %d, not an RP_EXT_* of "
                      "raypace_testing.h", n + 1, (int)h->type);
    bit = 1u << h->type;
    if (seen & bit)
      return rp__fail(ctx, RP_EINVAL, "rp_device_create: desc->next holds "
                      "two %s structs", h->type == RP_EXT_FAULTS
                                           ? "rp_fault_desc"
                                           : "rp_test_backend_desc");
    seen |= bit;
    if (h->type == RP_EXT_FAULTS)
      *faults = (const rp_fault_desc *)(const void *)h;
  }
  if ((seen & (1u << RP_EXT_TEST_BACKEND)) &&
      (name == NULL || strcmp(name, rp__test_backend.name) != 0))
    return rp__fail(ctx, RP_EINVAL, "rp_device_create: desc->next holds "
                    "an rp_test_backend_desc, which is for backend 'test', "
                    "but the device opens %s%s%s", name ? "'" : "",
                    name ? name : "the first backend with a device",
                    name ? "'" : "");
  return *faults != NULL ? rp__faults_check(ctx, *faults) : 0;
}
