/* Product tier (README, "Headers"): raypace version numbers. */
#ifndef RAYPACE_VERSION_H
#define RAYPACE_VERSION_H

#define RP_VERSION_MAJOR 0
#define RP_VERSION_MINOR 1
#define RP_VERSION_PATCH 0
#define RP_VERSION_HEX                                                       \
  ((RP_VERSION_MAJOR << 16) | (RP_VERSION_MINOR << 8) | RP_VERSION_PATCH)

#endif /* RAYPACE_VERSION_H */
