/* rp_device_desc's extension chain (raypace_testing.h): the testing
 * tier's structs, Vulkan pNext style. The front end checks the whole
 * chain before it opens anything, so that a host backend and the fault
 * wrapper can then look up their own struct without a check of their
 * own. */
#include "device.h"

const rp_ext_header *rp__ext_find(const void *next, rp_ext_type type) {
  const rp_ext_header *h;
  for (h = next; h != NULL; h = h->next)
    if (h->type == type)
      return h;
  return NULL;
}

int rp__ext_check(rp_context *ctx, const void *next,
                  const rp_fault_desc **faults) {
  const rp_ext_header *h = next;
  uint32_t seen = 0, n;
  *faults = NULL;
  for (n = 0; h != NULL; h = h->next, n++) {
    uint32_t bit;
    if (h->type != RP_EXT_FAULTS)
      return rp__fail(ctx, RP_EINVAL, "rp_device_create: extension struct "
                      "%u of desc->next has type %d, not an RP_EXT_* of "
                      "raypace_testing.h", n + 1, (int)h->type);
    bit = 1u << h->type;
    if (seen & bit)
      return rp__fail(ctx, RP_EINVAL, "rp_device_create: desc->next holds "
                      "two rp_fault_desc structs");
    seen |= bit;
    *faults = (const rp_fault_desc *)(const void *)h;
  }
  return *faults != NULL ? rp__faults_check(ctx, *faults) : 0;
}
