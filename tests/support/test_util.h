/* Helpers shared by the cmocka tests. */
#ifndef RP_TEST_UTIL_H
#define RP_TEST_UTIL_H

#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>

#include <cmocka.h>

#include "raypace.h"

/* The shared data folder (RP_SHARED_DATA), or NULL when it is absent: tests
 * that need real volumes call skip() then. */
const char *rp_test_data_dir(void);
/* Path of a shared volume's sidecar "<dir>/<name>/<name>.txt" in `buf`;
 * returns NULL when the folder or the file is absent. */
const char *rp_test_data_volume(const char *name, char *buf, size_t len);
/* The data set names in the shared folder (sidecar present), NULL-ended;
 * empty when absent. Static storage. */
const char *const *rp_test_data_names(void);
/* A scratch directory for files a test writes (created if missing). */
const char *rp_test_tmp_dir(void);
/* Writes `len` bytes to tmp/<name>, returns the full path (static buffer
 * rotated over 8 calls). */
const char *rp_test_write_file(const char *name, const void *data,
                               size_t len);
/* A context with defaults; asserts on failure. */
rp_context *rp_test_context(void);

#endif
