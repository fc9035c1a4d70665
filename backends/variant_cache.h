/* The kernel-variant cache every device backend keeps: one bound and one
 * eviction rule (backends/README.md, "Kernel variants").
 *
 * A backend specialises its kernels per frame state (effects compiled in
 * or out, the fetch-counting variant, the voxel type, ...). Each such
 * kernel is a variant, named by a uint32 key that says everything it was
 * built for. A device holds at most RP_VARIANT_CACHE_SIZE of them, so
 * that a long session of changing effects keeps a bounded number of
 * driver programs or pipelines alive. The thread that owns the impl (the
 * ops' thread) builds what an op needs when it is missing and, when the
 * table is full, replaces the least recently used entry. `prepare`, on
 * another thread, only fills a free entry and drops what it built
 * otherwise: it never evicts what the owner may be about to use. The
 * table has a fixed size, so neither thread ever allocates for it.
 *
 * This table holds the keys and the use stamps; a backend keeps its
 * driver objects (cl_program and cl_kernel, VkPipeline) in an array of
 * the same size, at the same index. Every call below is made under the
 * backend's lock. Nothing here is part of the public API. */
#ifndef RP_VARIANT_CACHE_H
#define RP_VARIANT_CACHE_H

#include <stdint.h>

/* Two variants per frame (depth pass and raycast) for a dozen effect
 * sets and step kinds, with room for the counting variants, the ERT
 * pre-pass and AO. */
#define RP_VARIANT_CACHE_SIZE 32

/* An op looks up at most two variants before it runs them (the depth
 * pass a raycast records ahead of itself). The one looked up first is
 * then the most recently used, so with two entries or more the second
 * lookup's eviction never takes it. */
_Static_assert(RP_VARIANT_CACHE_SIZE >= 2,
               "an op holds two variants at once");

/* What a backend's table holds and has done; tests read it. */
typedef struct rp_variant_stats {
  uint32_t count;     /* variants held now, never over the bound */
  uint32_t builds;    /* variants built, by either thread, kept or not */
  uint32_t dropped;   /* of those, not kept: prepare with no free entry,
                         or the other thread had put the key first */
  uint32_t hits;      /* the owner's lookups that found their variant */
  uint32_t evictions; /* entries the owner replaced with another */
} rp_variant_stats;

typedef struct rp_variant_slot {
  uint32_t key;
  uint32_t used;     /* 0: a free entry */
  uint64_t last_use; /* the table's clock when last used */
} rp_variant_slot;

typedef struct rp_variant_table {
  rp_variant_slot slot[RP_VARIANT_CACHE_SIZE];
  uint64_t clock;
  rp_variant_stats stats;
} rp_variant_table;

/* What rp__variant_insert did with a variant just built. */
typedef enum rp_variant_fate {
  RP_VARIANT_KEPT,     /* in a free entry at *index */
  RP_VARIANT_REPLACED, /* at *index, whose old variant the caller
                          releases once it has taken it out */
  RP_VARIANT_HAD,      /* the key was there already, at *index: the
                          caller releases what it built and uses that */
  RP_VARIANT_DROPPED   /* no free entry and not the owner: the caller
                          releases what it built */
} rp_variant_fate;

/* The entry holding `key`, or -1; stamps nothing (prepare's look). */
static inline int rp__variant_find(const rp_variant_table *t, uint32_t key) {
  int i;
  for (i = 0; i < RP_VARIANT_CACHE_SIZE; i++)
    if (t->slot[i].used && t->slot[i].key == key)
      return i;
  return -1;
}

/* The owner's lookup: the entry holding `key`, stamped as used now and
 * counted as a hit, or -1. */
static inline int rp__variant_use(rp_variant_table *t, uint32_t key) {
  int i = rp__variant_find(t, key);
  if (i >= 0) {
    t->slot[i].last_use = ++t->clock;
    t->stats.hits++;
  }
  return i;
}

/* Finds the entry for a variant of `key` just built, in *index (see
 * rp_variant_fate). `owner`: the impl's own thread, which takes the
 * least recently used entry when none is free; prepare (owner 0) takes
 * only a free one. A variant kept is stamped as used now, and so is one
 * the owner finds there. */
static inline rp_variant_fate rp__variant_insert(rp_variant_table *t,
                                                 uint32_t key, int owner,
                                                 int *index) {
  rp_variant_fate fate;
  int i, pick = -1;
  t->stats.builds++;
  if ((i = rp__variant_find(t, key)) >= 0) {
    t->stats.dropped++;
    if (owner) {
      t->stats.hits++;
      t->slot[i].last_use = ++t->clock;
    }
    *index = i;
    return RP_VARIANT_HAD;
  }
  for (i = 0; i < RP_VARIANT_CACHE_SIZE && pick < 0; i++)
    if (!t->slot[i].used)
      pick = i;
  fate = RP_VARIANT_KEPT;
  if (pick < 0) {
    if (!owner) {
      t->stats.dropped++;
      *index = -1;
      return RP_VARIANT_DROPPED;
    }
    pick = 0;
    for (i = 1; i < RP_VARIANT_CACHE_SIZE; i++)
      if (t->slot[i].last_use < t->slot[pick].last_use)
        pick = i;
    t->stats.evictions++;
    fate = RP_VARIANT_REPLACED;
  } else {
    t->stats.count++;
  }
  t->slot[pick].key = key;
  t->slot[pick].used = 1;
  t->slot[pick].last_use = ++t->clock;
  *index = pick;
  return fate;
}

/* Each backend's figures for tests (impl as create returned it), read
 * under its lock, so a prepare may be running meanwhile. Defined only
 * where the backend is compiled in. */
void rp_cl__variant_stats(void *impl, rp_variant_stats *out);
void rp_vk__variant_stats(void *impl, rp_variant_stats *out);

#endif /* RP_VARIANT_CACHE_H */
