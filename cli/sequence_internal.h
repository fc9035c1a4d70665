/* What the two halves of the raypace command's sequences share: the
 * parsed form a document becomes (cli/sequence_json.c, the format) and
 * that a frame's state is resolved from (cli/sequence.c).
 *
 * A parsed sequence is four tracks sorted by frame: camera keyframes
 * (every value resolved, so a frame needs only its two neighbouring
 * keys), and the step changes of transfer function, target and effects.
 * Everything it holds goes through its context's allocator. */
#ifndef RP_CLI_SEQUENCE_INTERNAL_H
#define RP_CLI_SEQUENCE_INTERNAL_H

#include <stddef.h>
#include <stdint.h>

#include "raypace_sequence.h"

/* Defaults of a state before the first change of each track. */
#define RP__SEQ_DEFAULT_DISTANCE 3.0
#define RP__SEQ_DEFAULT_FOV 40.0
#define RP__SEQ_DEFAULT_FRACTION 0.5


/* A camera keyframe with every value resolved (missing fields were taken
 * from the previous keyframe). `frame` comes first: find_last reads it
 * through a stride. */
typedef struct seq_key {
  uint32_t frame;
  double az, el, dist, pan[2], fov;
  int cut; /* "cut": the frames since the previous keyframe hold it, and
              this one jumps */
} seq_key;

/* A step change on one of the three step tracks; only the fields of its
 * track are meaningful. */
typedef struct seq_step {
  uint32_t frame;
  int tf;
  double target_ms, target_fraction;
  uint32_t effects;
} seq_step;

typedef struct seq_tf {
  char *preset;        /* NULL for control points */
  rp_tf_point *points;
  int count;
  float reference_step;
  int lut_size;
} seq_tf;

struct rp_sequence {
  rp_context *ctx;
  char *name;
  char *about;
  uint32_t frames;
  rp_projection projection;
  seq_tf *tfs;
  int tf_count;
  seq_key *keys;
  size_t key_count;
  seq_step *tf_steps;
  size_t tf_step_count;
  seq_step *target_steps;
  size_t target_step_count;
  seq_step *effect_steps;
  size_t effect_step_count;
};

#endif /* RP_CLI_SEQUENCE_INTERNAL_H */
