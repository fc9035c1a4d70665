/* Interaction sequences, the raypace command's (docs/sequences.md): the
 * built-in sequences, and what a parsed sequence says about each frame.
 * A frame's state is a binary search in each track, so a replay may ask
 * for frames in any order at no cost per frame beyond that. The format
 * and its parser are cli/sequence_json.c. */
#include <math.h>
#include <string.h>

#include "raygen.h" /* RP__PARALLEL_EPS: the camera basis is raygen's */
#include "sequence_internal.h"

#define RP__SEQ_PI 3.14159265358979323846

/* ---- Built-in sequences -------------------------------------------------- */

/* Written in the file format and parsed by the same parser, so each is
 * also an example of it. Targets are fractions of the no-adaptation frame
 * time: they mean the same on any machine. */

static const char builtin_orbit[] =
    "{\n"
    "  \"version\": 1,\n"
    "  \"name\": \"orbit\",\n"
    "  \"about\": \"slow full orbit (2 degrees a frame) at a fixed "
    "transfer function: the steady case\",\n"
    "  \"frames\": 180,\n"
    "  \"tfs\": [\"minmax-bone\"],\n"
    "  \"events\": [\n"
    "    {\"frame\": 0,\n"
    "     \"camera\": {\"azimuth\": 0, \"elevation\": 20, "
    "\"distance\": 2.5},\n"
    "     \"tf\": 0, \"target_fraction\": 0.5, "
    "\"effects\": [\"ert\", \"skip\"]},\n"
    "    {\"frame\": 179, \"camera\": {\"azimuth\": 358}}\n"
    "  ]\n"
    "}\n";

static const char builtin_tf_switch[] =
    "{\n"
    "  \"version\": 1,\n"
    "  \"name\": \"tf-switch\",\n"
    "  \"about\": \"still camera, abrupt switches between a nearly "
    "transparent and an opaque transfer function every 20 frames\",\n"
    "  \"frames\": 160,\n"
    "  \"tfs\": [\"nearly-transparent\", \"opaque\"],\n"
    "  \"events\": [\n"
    "    {\"frame\": 0,\n"
    "     \"comment\": \"the hard case for controllers that react to the "
    "last frame: its cost says nothing about the next one\",\n"
    "     \"camera\": {\"azimuth\": 30, \"elevation\": 20, "
    "\"distance\": 2.5},\n"
    "     \"tf\": 0, \"target_fraction\": 0.5, "
    "\"effects\": [\"ert\", \"skip\"]},\n"
    "    {\"frame\": 20, \"tf\": 1},\n"
    "    {\"frame\": 40, \"tf\": 0},\n"
    "    {\"frame\": 60, \"tf\": 1},\n"
    "    {\"frame\": 80, \"tf\": 0},\n"
    "    {\"frame\": 100, \"tf\": 1},\n"
    "    {\"frame\": 120, \"tf\": 0},\n"
    "    {\"frame\": 140, \"tf\": 1}\n"
    "  ]\n"
    "}\n";

static const char builtin_zoom_in[] =
    "{\n"
    "  \"version\": 1,\n"
    "  \"name\": \"zoom-in\",\n"
    "  \"about\": \"zoom from far outside (4 radii) to inside the volume "
    "(0.3 radii), then hold\",\n"
    "  \"frames\": 150,\n"
    "  \"tfs\": [\"minmax-bone\"],\n"
    "  \"events\": [\n"
    "    {\"frame\": 0,\n"
    "     \"camera\": {\"azimuth\": 30, \"elevation\": 15, "
    "\"distance\": 4},\n"
    "     \"tf\": 0, \"target_fraction\": 0.5, "
    "\"effects\": [\"ert\", \"skip\"]},\n"
    "    {\"frame\": 15, \"camera\": {}},\n"
    "    {\"frame\": 135, \"camera\": {\"distance\": 0.3}}\n"
    "  ]\n"
    "}\n";

static const char builtin_mixed[] =
    "{\n"
    "  \"version\": 1,\n"
    "  \"name\": \"mixed\",\n"
    "  \"about\": \"orbit with zoom and pan, transfer function switches, "
    "a tighter target and shading toggled on and off\",\n"
    "  \"frames\": 200,\n"
    "  \"tfs\": [\"minmax-bone\", \"minmax-soft\", \"opaque\", "
    "\"nearly-transparent\"],\n"
    "  \"events\": [\n"
    "    {\"frame\": 0,\n"
    "     \"camera\": {\"azimuth\": 0, \"elevation\": 10, \"distance\": 3,\n"
    "                \"pan\": [0, 0], \"fov\": 40},\n"
    "     \"tf\": 0, \"target_fraction\": 0.5, "
    "\"effects\": [\"ert\", \"skip\"]},\n"
    "    {\"frame\": 40, \"tf\": 1},\n"
    "    {\"frame\": 60, \"effects\": [\"shading\", \"ert\", \"skip\"]},\n"
    "    {\"frame\": 80,\n"
    "     \"camera\": {\"azimuth\": 120, \"elevation\": 35, "
    "\"distance\": 1.8,\n"
    "                \"pan\": [0.2, -0.1]}},\n"
    "    {\"frame\": 100, \"tf\": 2, \"target_fraction\": 0.3},\n"
    "    {\"frame\": 120, \"tf\": 3},\n"
    "    {\"frame\": 140, \"effects\": [\"ert\", \"skip\"]},\n"
    "    {\"frame\": 160, \"tf\": 0,\n"
    "     \"camera\": {\"azimuth\": 200, \"elevation\": 10, "
    "\"distance\": 2.5,\n"
    "                \"pan\": [0, 0]}},\n"
    "    {\"frame\": 199, \"camera\": {\"azimuth\": 240, \"fov\": 30}}\n"
    "  ]\n"
    "}\n";

static const char builtin_ao_tf_switch[] =
    "{\n"
    "  \"version\": 1,\n"
    "  \"name\": \"ao-tf-switch\",\n"
    "  \"about\": \"still camera with shading and ambient occlusion, "
    "switching between soft tissue and bone every 40 frames: each switch "
    "recomputes the AO volume\",\n"
    "  \"frames\": 160,\n"
    "  \"tfs\": [\"minmax-soft\", \"minmax-bone\"],\n"
    "  \"events\": [\n"
    "    {\"frame\": 0,\n"
    "     \"camera\": {\"azimuth\": 30, \"elevation\": 20, "
    "\"distance\": 2.5},\n"
    "     \"tf\": 0, \"target_fraction\": 0.5, "
    "\"effects\": [\"shading\", \"ao\", \"ert\", \"skip\"]},\n"
    "    {\"frame\": 40, \"tf\": 1},\n"
    "    {\"frame\": 80, \"tf\": 0},\n"
    "    {\"frame\": 120, \"tf\": 1}\n"
    "  ]\n"
    "}\n";

/* What users actually play (M10): a TF window slid across the data
 * range, head-like jitter, cuts that come with a TF switch, target steps
 * and effects toggled while the camera moves. */

static const char builtin_tf_window[] =
    "{\n"
    "  \"version\": 1,\n"
    "  \"name\": \"tf-window\",\n"
    "  \"about\": \"orbit (1 degree a frame) while a narrow transfer "
    "function window, 0.13 of the data range wide, slides across it from 0 "
    "to 1 in steps of 0.03 every 5 frames\",\n"
    "  \"frames\": 150,\n"
    "  \"tfs\": [\n"
    "    {\"points\": [[0, 1, 0.8, 0.6, 0], [0.065, 1, 0.8, 0.6, 0.8],\n"
    "                [0.13, 1, 0.8, 0.6, 0]]},\n"
    "    {\"points\": [[0.03, 1, 0.8, 0.6, 0], [0.095, 1, 0.8, 0.6, 0.8],\n"
    "                [0.16, 1, 0.8, 0.6, 0]]},\n"
    "    {\"points\": [[0.06, 1, 0.8, 0.6, 0], [0.125, 1, 0.8, 0.6, 0.8],\n"
    "                [0.19, 1, 0.8, 0.6, 0]]},\n"
    "    {\"points\": [[0.09, 1, 0.8, 0.6, 0], [0.155, 1, 0.8, 0.6, 0.8],\n"
    "                [0.22, 1, 0.8, 0.6, 0]]},\n"
    "    {\"points\": [[0.12, 1, 0.8, 0.6, 0], [0.185, 1, 0.8, 0.6, 0.8],\n"
    "                [0.25, 1, 0.8, 0.6, 0]]},\n"
    "    {\"points\": [[0.15, 1, 0.8, 0.6, 0], [0.215, 1, 0.8, 0.6, 0.8],\n"
    "                [0.28, 1, 0.8, 0.6, 0]]},\n"
    "    {\"points\": [[0.18, 1, 0.8, 0.6, 0], [0.245, 1, 0.8, 0.6, 0.8],\n"
    "                [0.31, 1, 0.8, 0.6, 0]]},\n"
    "    {\"points\": [[0.21, 1, 0.8, 0.6, 0], [0.275, 1, 0.8, 0.6, 0.8],\n"
    "                [0.34, 1, 0.8, 0.6, 0]]},\n"
    "    {\"points\": [[0.24, 1, 0.8, 0.6, 0], [0.305, 1, 0.8, 0.6, 0.8],\n"
    "                [0.37, 1, 0.8, 0.6, 0]]},\n"
    "    {\"points\": [[0.27, 1, 0.8, 0.6, 0], [0.335, 1, 0.8, 0.6, 0.8],\n"
    "                [0.4, 1, 0.8, 0.6, 0]]},\n"
    "    {\"points\": [[0.3, 1, 0.8, 0.6, 0], [0.365, 1, 0.8, 0.6, 0.8],\n"
    "                [0.43, 1, 0.8, 0.6, 0]]},\n"
    "    {\"points\": [[0.33, 1, 0.8, 0.6, 0], [0.395, 1, 0.8, 0.6, 0.8],\n"
    "                [0.46, 1, 0.8, 0.6, 0]]},\n"
    "    {\"points\": [[0.36, 1, 0.8, 0.6, 0], [0.425, 1, 0.8, 0.6, 0.8],\n"
    "                [0.49, 1, 0.8, 0.6, 0]]},\n"
    "    {\"points\": [[0.39, 1, 0.8, 0.6, 0], [0.455, 1, 0.8, 0.6, 0.8],\n"
    "                [0.52, 1, 0.8, 0.6, 0]]},\n"
    "    {\"points\": [[0.42, 1, 0.8, 0.6, 0], [0.485, 1, 0.8, 0.6, 0.8],\n"
    "                [0.55, 1, 0.8, 0.6, 0]]},\n"
    "    {\"points\": [[0.45, 1, 0.8, 0.6, 0], [0.515, 1, 0.8, 0.6, 0.8],\n"
    "                [0.58, 1, 0.8, 0.6, 0]]},\n"
    "    {\"points\": [[0.48, 1, 0.8, 0.6, 0], [0.545, 1, 0.8, 0.6, 0.8],\n"
    "                [0.61, 1, 0.8, 0.6, 0]]},\n"
    "    {\"points\": [[0.51, 1, 0.8, 0.6, 0], [0.575, 1, 0.8, 0.6, 0.8],\n"
    "                [0.64, 1, 0.8, 0.6, 0]]},\n"
    "    {\"points\": [[0.54, 1, 0.8, 0.6, 0], [0.605, 1, 0.8, 0.6, 0.8],\n"
    "                [0.67, 1, 0.8, 0.6, 0]]},\n"
    "    {\"points\": [[0.57, 1, 0.8, 0.6, 0], [0.635, 1, 0.8, 0.6, 0.8],\n"
    "                [0.7, 1, 0.8, 0.6, 0]]},\n"
    "    {\"points\": [[0.6, 1, 0.8, 0.6, 0], [0.665, 1, 0.8, 0.6, 0.8],\n"
    "                [0.73, 1, 0.8, 0.6, 0]]},\n"
    "    {\"points\": [[0.63, 1, 0.8, 0.6, 0], [0.695, 1, 0.8, 0.6, 0.8],\n"
    "                [0.76, 1, 0.8, 0.6, 0]]},\n"
    "    {\"points\": [[0.66, 1, 0.8, 0.6, 0], [0.725, 1, 0.8, 0.6, 0.8],\n"
    "                [0.79, 1, 0.8, 0.6, 0]]},\n"
    "    {\"points\": [[0.69, 1, 0.8, 0.6, 0], [0.755, 1, 0.8, 0.6, 0.8],\n"
    "                [0.82, 1, 0.8, 0.6, 0]]},\n"
    "    {\"points\": [[0.72, 1, 0.8, 0.6, 0], [0.785, 1, 0.8, 0.6, 0.8],\n"
    "                [0.85, 1, 0.8, 0.6, 0]]},\n"
    "    {\"points\": [[0.75, 1, 0.8, 0.6, 0], [0.815, 1, 0.8, 0.6, 0.8],\n"
    "                [0.88, 1, 0.8, 0.6, 0]]},\n"
    "    {\"points\": [[0.78, 1, 0.8, 0.6, 0], [0.845, 1, 0.8, 0.6, 0.8],\n"
    "                [0.91, 1, 0.8, 0.6, 0]]},\n"
    "    {\"points\": [[0.81, 1, 0.8, 0.6, 0], [0.875, 1, 0.8, 0.6, 0.8],\n"
    "                [0.94, 1, 0.8, 0.6, 0]]},\n"
    "    {\"points\": [[0.84, 1, 0.8, 0.6, 0], [0.905, 1, 0.8, 0.6, 0.8],\n"
    "                [0.97, 1, 0.8, 0.6, 0]]},\n"
    "    {\"points\": [[0.87, 1, 0.8, 0.6, 0], [0.935, 1, 0.8, 0.6, 0.8],\n"
    "                [1, 1, 0.8, 0.6, 0]]}\n"
    "  ],\n"
    "  \"events\": [\n"
    "    {\"frame\": 0,\n"
    "     \"camera\": {\"azimuth\": 0, \"elevation\": 20, \"distance\": "
    "2.5},\n"
    "     \"tf\": 0, \"target_fraction\": 0.5, \"effects\": [\"ert\", "
    "\"skip\"]},\n"
    "    {\"frame\": 5, \"tf\": 1},\n"
    "    {\"frame\": 10, \"tf\": 2},\n"
    "    {\"frame\": 15, \"tf\": 3},\n"
    "    {\"frame\": 20, \"tf\": 4},\n"
    "    {\"frame\": 25, \"tf\": 5},\n"
    "    {\"frame\": 30, \"tf\": 6},\n"
    "    {\"frame\": 35, \"tf\": 7},\n"
    "    {\"frame\": 40, \"tf\": 8},\n"
    "    {\"frame\": 45, \"tf\": 9},\n"
    "    {\"frame\": 50, \"tf\": 10},\n"
    "    {\"frame\": 55, \"tf\": 11},\n"
    "    {\"frame\": 60, \"tf\": 12},\n"
    "    {\"frame\": 65, \"tf\": 13},\n"
    "    {\"frame\": 70, \"tf\": 14},\n"
    "    {\"frame\": 75, \"tf\": 15},\n"
    "    {\"frame\": 80, \"tf\": 16},\n"
    "    {\"frame\": 85, \"tf\": 17},\n"
    "    {\"frame\": 90, \"tf\": 18},\n"
    "    {\"frame\": 95, \"tf\": 19},\n"
    "    {\"frame\": 100, \"tf\": 20},\n"
    "    {\"frame\": 105, \"tf\": 21},\n"
    "    {\"frame\": 110, \"tf\": 22},\n"
    "    {\"frame\": 115, \"tf\": 23},\n"
    "    {\"frame\": 120, \"tf\": 24},\n"
    "    {\"frame\": 125, \"tf\": 25},\n"
    "    {\"frame\": 130, \"tf\": 26},\n"
    "    {\"frame\": 135, \"tf\": 27},\n"
    "    {\"frame\": 140, \"tf\": 28},\n"
    "    {\"frame\": 145, \"tf\": 29},\n"
    "    {\"frame\": 149, \"camera\": {\"azimuth\": 149}}\n"
    "  ]\n"
    "}\n";

static const char builtin_head_motion[] =
    "{\n"
    "  \"version\": 1,\n"
    "  \"name\": \"head-motion\",\n"
    "  \"about\": \"approach from 3.4 to 1.6 radii with small fast "
    "head-like oscillations: azimuth within 3 degrees each way over 8 "
    "frames, elevation within 2 over 16\",\n"
    "  \"frames\": 121,\n"
    "  \"tfs\": [\"minmax-soft\"],\n"
    "  \"events\": [\n"
    "    {\"frame\": 0,\n"
    "     \"camera\": {\"azimuth\": 27, \"elevation\": 20, \"distance\": "
    "3.4},\n"
    "     \"tf\": 0, \"target_fraction\": 0.5, \"effects\": [\"ert\", "
    "\"skip\"]},\n"
    "    {\"frame\": 4, \"camera\": {\"azimuth\": 33, \"elevation\": 22, "
    "\"distance\": 3.34}},\n"
    "    {\"frame\": 8, \"camera\": {\"azimuth\": 27, \"elevation\": 20, "
    "\"distance\": 3.28}},\n"
    "    {\"frame\": 12, \"camera\": {\"azimuth\": 33, \"elevation\": 18, "
    "\"distance\": 3.22}},\n"
    "    {\"frame\": 16, \"camera\": {\"azimuth\": 27, \"elevation\": 20, "
    "\"distance\": 3.16}},\n"
    "    {\"frame\": 20, \"camera\": {\"azimuth\": 33, \"elevation\": 22, "
    "\"distance\": 3.1}},\n"
    "    {\"frame\": 24, \"camera\": {\"azimuth\": 27, \"elevation\": 20, "
    "\"distance\": 3.04}},\n"
    "    {\"frame\": 28, \"camera\": {\"azimuth\": 33, \"elevation\": 18, "
    "\"distance\": 2.98}},\n"
    "    {\"frame\": 32, \"camera\": {\"azimuth\": 27, \"elevation\": 20, "
    "\"distance\": 2.92}},\n"
    "    {\"frame\": 36, \"camera\": {\"azimuth\": 33, \"elevation\": 22, "
    "\"distance\": 2.86}},\n"
    "    {\"frame\": 40, \"camera\": {\"azimuth\": 27, \"elevation\": 20, "
    "\"distance\": 2.8}},\n"
    "    {\"frame\": 44, \"camera\": {\"azimuth\": 33, \"elevation\": 18, "
    "\"distance\": 2.74}},\n"
    "    {\"frame\": 48, \"camera\": {\"azimuth\": 27, \"elevation\": 20, "
    "\"distance\": 2.68}},\n"
    "    {\"frame\": 52, \"camera\": {\"azimuth\": 33, \"elevation\": 22, "
    "\"distance\": 2.62}},\n"
    "    {\"frame\": 56, \"camera\": {\"azimuth\": 27, \"elevation\": 20, "
    "\"distance\": 2.56}},\n"
    "    {\"frame\": 60, \"camera\": {\"azimuth\": 33, \"elevation\": 18, "
    "\"distance\": 2.5}},\n"
    "    {\"frame\": 64, \"camera\": {\"azimuth\": 27, \"elevation\": 20, "
    "\"distance\": 2.44}},\n"
    "    {\"frame\": 68, \"camera\": {\"azimuth\": 33, \"elevation\": 22, "
    "\"distance\": 2.38}},\n"
    "    {\"frame\": 72, \"camera\": {\"azimuth\": 27, \"elevation\": 20, "
    "\"distance\": 2.32}},\n"
    "    {\"frame\": 76, \"camera\": {\"azimuth\": 33, \"elevation\": 18, "
    "\"distance\": 2.26}},\n"
    "    {\"frame\": 80, \"camera\": {\"azimuth\": 27, \"elevation\": 20, "
    "\"distance\": 2.2}},\n"
    "    {\"frame\": 84, \"camera\": {\"azimuth\": 33, \"elevation\": 22, "
    "\"distance\": 2.14}},\n"
    "    {\"frame\": 88, \"camera\": {\"azimuth\": 27, \"elevation\": 20, "
    "\"distance\": 2.08}},\n"
    "    {\"frame\": 92, \"camera\": {\"azimuth\": 33, \"elevation\": 18, "
    "\"distance\": 2.02}},\n"
    "    {\"frame\": 96, \"camera\": {\"azimuth\": 27, \"elevation\": 20, "
    "\"distance\": 1.96}},\n"
    "    {\"frame\": 100, \"camera\": {\"azimuth\": 33, \"elevation\": 22, "
    "\"distance\": 1.9}},\n"
    "    {\"frame\": 104, \"camera\": {\"azimuth\": 27, \"elevation\": 20, "
    "\"distance\": 1.84}},\n"
    "    {\"frame\": 108, \"camera\": {\"azimuth\": 33, \"elevation\": 18, "
    "\"distance\": 1.78}},\n"
    "    {\"frame\": 112, \"camera\": {\"azimuth\": 27, \"elevation\": 20, "
    "\"distance\": 1.72}},\n"
    "    {\"frame\": 116, \"camera\": {\"azimuth\": 33, \"elevation\": 22, "
    "\"distance\": 1.66}},\n"
    "    {\"frame\": 120, \"camera\": {\"azimuth\": 27, \"elevation\": 20, "
    "\"distance\": 1.6}}\n"
    "  ]\n"
    "}\n";

static const char builtin_cut_switch[] =
    "{\n"
    "  \"version\": 1,\n"
    "  \"name\": \"cut-switch\",\n"
    "  \"about\": \"five shots of 30 frames, each a slow orbit; each cut to "
    "a new view (side, elevation and distance) comes with a transfer "
    "function switch on the same frame\",\n"
    "  \"frames\": 150,\n"
    "  \"tfs\": [\"minmax-bone\", \"minmax-soft\", \"opaque\", "
    "\"nearly-transparent\"],\n"
    "  \"events\": [\n"
    "    {\"frame\": 0,\n"
    "     \"camera\": {\"azimuth\": 0, \"elevation\": 20, \"distance\": "
    "2.5},\n"
    "     \"tf\": 0, \"target_fraction\": 0.5, \"effects\": [\"ert\", "
    "\"skip\"]},\n"
    "    {\"frame\": 29, \"camera\": {\"azimuth\": 14.5}},\n"
    "    {\"frame\": 30, \"tf\": 1,\n"
    "     \"camera\": {\"azimuth\": 120, \"elevation\": 35, \"distance\": "
    "1.6,\n"
    "                \"cut\": true}},\n"
    "    {\"frame\": 59, \"camera\": {\"azimuth\": 134.5}},\n"
    "    {\"frame\": 60, \"tf\": 2,\n"
    "     \"camera\": {\"azimuth\": 250, \"elevation\": -10, \"distance\": "
    "3.2,\n"
    "                \"cut\": true}},\n"
    "    {\"frame\": 89, \"camera\": {\"azimuth\": 264.5}},\n"
    "    {\"frame\": 90, \"tf\": 3,\n"
    "     \"camera\": {\"azimuth\": 30, \"elevation\": 60, \"distance\": "
    "1.4,\n"
    "                \"cut\": true}},\n"
    "    {\"frame\": 119, \"camera\": {\"azimuth\": 44.5}},\n"
    "    {\"frame\": 120, \"tf\": 0,\n"
    "     \"camera\": {\"azimuth\": 180, \"elevation\": 15, \"distance\": "
    "2.2,\n"
    "                \"cut\": true}},\n"
    "    {\"frame\": 149, \"camera\": {\"azimuth\": 194.5}}\n"
    "  ]\n"
    "}\n";

static const char builtin_target_steps[] =
    "{\n"
    "  \"version\": 1,\n"
    "  \"name\": \"target-steps\",\n"
    "  \"about\": \"slow orbit (1 degree a frame) while the target steps "
    "from 0.5 to 0.2 to 0.8 of the frame time without adaptation, every 50 "
    "frames\",\n"
    "  \"frames\": 150,\n"
    "  \"tfs\": [\"minmax-bone\"],\n"
    "  \"events\": [\n"
    "    {\"frame\": 0,\n"
    "     \"camera\": {\"azimuth\": 0, \"elevation\": 20, \"distance\": "
    "2.5},\n"
    "     \"tf\": 0, \"target_fraction\": 0.5, \"effects\": [\"ert\", "
    "\"skip\"]},\n"
    "    {\"frame\": 50, \"target_fraction\": 0.2},\n"
    "    {\"frame\": 100, \"target_fraction\": 0.8},\n"
    "    {\"frame\": 149, \"camera\": {\"azimuth\": 149}}\n"
    "  ]\n"
    "}\n";

static const char builtin_effects_motion[] =
    "{\n"
    "  \"version\": 1,\n"
    "  \"name\": \"effects-motion\",\n"
    "  \"about\": \"orbit with zoom (3 to 1.8 radii) while shading is "
    "toggled every 25 frames and ambient occlusion is turned on and off "
    "once\",\n"
    "  \"frames\": 150,\n"
    "  \"tfs\": [\"minmax-soft\"],\n"
    "  \"events\": [\n"
    "    {\"frame\": 0,\n"
    "     \"camera\": {\"azimuth\": 0, \"elevation\": 15, \"distance\": 3},\n"
    "     \"tf\": 0, \"target_fraction\": 0.5, \"effects\": [\"ert\", "
    "\"skip\"]},\n"
    "    {\"frame\": 25, \"effects\": [\"shading\", \"ert\", \"skip\"]},\n"
    "    {\"frame\": 50, \"effects\": [\"ert\", \"skip\"]},\n"
    "    {\"frame\": 75, \"effects\": [\"shading\", \"ao\", \"ert\", "
    "\"skip\"]},\n"
    "    {\"frame\": 100, \"effects\": [\"shading\", \"ert\", \"skip\"]},\n"
    "    {\"frame\": 125, \"effects\": [\"ert\", \"skip\"]},\n"
    "    {\"frame\": 149, \"camera\": {\"azimuth\": 149, \"distance\": 1.8}}\n"
    "  ]\n"
    "}\n";

typedef struct builtin {
  const char *name;
  const char *about; /* equal to the document's "about" (tested) */
  const char *json;
} builtin;

static const builtin builtins[] = {
    {"orbit",
     "slow full orbit (2 degrees a frame) at a fixed transfer function: "
     "the steady case",
     builtin_orbit},
    {"tf-switch",
     "still camera, abrupt switches between a nearly transparent and an "
     "opaque transfer function every 20 frames",
     builtin_tf_switch},
    {"zoom-in",
     "zoom from far outside (4 radii) to inside the volume (0.3 radii), "
     "then hold",
     builtin_zoom_in},
    {"mixed",
     "orbit with zoom and pan, transfer function switches, a tighter "
     "target and shading toggled on and off",
     builtin_mixed},
    {"ao-tf-switch",
     "still camera with shading and ambient occlusion, switching between "
     "soft tissue and bone every 40 frames: each switch recomputes the AO "
     "volume",
     builtin_ao_tf_switch},
    {"tf-window",
     "orbit (1 degree a frame) while a narrow transfer function window, 0.13 "
     "of the data range wide, slides across it from 0 to 1 in steps of 0.03 "
     "every 5 frames",
     builtin_tf_window},
    {"head-motion",
     "approach from 3.4 to 1.6 radii with small fast head-like oscillations: "
     "azimuth within 3 degrees each way over 8 frames, elevation within 2 "
     "over 16",
     builtin_head_motion},
    {"cut-switch",
     "five shots of 30 frames, each a slow orbit; each cut to a new view "
     "(side, elevation and distance) comes with a transfer function switch "
     "on the same frame",
     builtin_cut_switch},
    {"target-steps",
     "slow orbit (1 degree a frame) while the target steps from 0.5 to 0.2 "
     "to 0.8 of the frame time without adaptation, every 50 frames",
     builtin_target_steps},
    {"effects-motion",
     "orbit with zoom (3 to 1.8 radii) while shading is toggled every 25 "
     "frames and ambient occlusion is turned on and off once",
     builtin_effects_motion},
};

#define RP__SEQ_BUILTINS (sizeof builtins / sizeof builtins[0])

const char *const *rp_sequence_builtin_names(void) {
  static const char *const names[] = {"orbit", "tf-switch", "zoom-in",
                                      "mixed", "ao-tf-switch", "tf-window",
                                      "head-motion", "cut-switch",
                                      "target-steps", "effects-motion",
                                      NULL};
  return names;
}

static const builtin *find_builtin(const char *name) {
  size_t i;
  if (name == NULL)
    return NULL;
  for (i = 0; i < RP__SEQ_BUILTINS; i++)
    if (strcmp(builtins[i].name, name) == 0)
      return &builtins[i];
  return NULL;
}

const char *rp_sequence_builtin_about(const char *name) {
  const builtin *b = find_builtin(name);
  return b != NULL ? b->about : NULL;
}

const char *rp_sequence_builtin_json(const char *name) {
  const builtin *b = find_builtin(name);
  return b != NULL ? b->json : NULL;
}


/* ---- Queries ------------------------------------------------------------- */

uint32_t rp_sequence_frames(const rp_sequence *s) {
  return s != NULL ? s->frames : 0;
}

const char *rp_sequence_name(const rp_sequence *s) {
  return s != NULL ? s->name : NULL;
}

const char *rp_sequence_about(const rp_sequence *s) {
  return s != NULL ? s->about : NULL;
}

int rp_sequence_tf_count(const rp_sequence *s) {
  return s != NULL ? s->tf_count : 0;
}

/* Index of the last entry whose frame is <= i, or -1 when none is. The
 * entries are sorted by frame, which is their first member. */
static long find_last(const void *base, size_t n, size_t stride,
                      uint32_t i) {
  size_t lo = 0, hi = n;
  while (lo < hi) {
    size_t mid = lo + (hi - lo) / 2;
    uint32_t f;
    memcpy(&f, (const char *)base + mid * stride, sizeof f);
    if (f <= i)
      lo = mid + 1;
    else
      hi = mid;
  }
  return (long)lo - 1;
}

/* Exact at both ends, and a held value stays bit-identical between the
 * keys, so a hold never reports a camera change. */
static double lerp(double a, double b, double t) {
  return a == b ? a : (1.0 - t) * a + t * b;
}

static void resolve(const rp_sequence *s, uint32_t i, rp_sequence_state *st) {
  long k;
  memset(st, 0, sizeof *st);
  st->frame = i;
  st->projection = s->projection;

  st->distance = RP__SEQ_DEFAULT_DISTANCE;
  st->fov_y_deg = RP__SEQ_DEFAULT_FOV;
  if (s->key_count > 0) {
    const seq_key *a, *b;
    double t = 0.0;
    k = find_last(s->keys, s->key_count, sizeof *s->keys, i);
    /* Before the first keyframe and after the last the camera holds. */
    if (k < 0)
      a = b = &s->keys[0];
    else if ((size_t)k + 1 >= s->key_count)
      a = b = &s->keys[k];
    else {
      a = &s->keys[k];
      b = &s->keys[k + 1];
      /* Up to a cut the camera holds; the cut's own frame is b's. */
      t = b->cut ? 0.0
                 : (double)(i - a->frame) / (double)(b->frame - a->frame);
    }
    st->camera_cut = k >= 0 && a->frame == i && a->cut;
    st->azimuth_deg = lerp(a->az, b->az, t);
    st->elevation_deg = lerp(a->el, b->el, t);
    st->distance = lerp(a->dist, b->dist, t);
    st->pan[0] = lerp(a->pan[0], b->pan[0], t);
    st->pan[1] = lerp(a->pan[1], b->pan[1], t);
    st->fov_y_deg = lerp(a->fov, b->fov, t);
  }

  k = find_last(s->tf_steps, s->tf_step_count, sizeof *s->tf_steps, i);
  st->tf = k >= 0 ? s->tf_steps[k].tf : 0;

  k = find_last(s->target_steps, s->target_step_count,
                sizeof *s->target_steps, i);
  if (k >= 0) {
    st->target_ms = s->target_steps[k].target_ms;
    st->target_fraction = s->target_steps[k].target_fraction;
  } else {
    st->target_fraction = RP__SEQ_DEFAULT_FRACTION;
  }

  k = find_last(s->effect_steps, s->effect_step_count,
                sizeof *s->effect_steps, i);
  st->effects = k >= 0 ? s->effect_steps[k].effects : 0;
}

/* The view direction of an orbit, from the centre to the eye
 * (rp_camera_orbit). */
static void view_dir(const rp_sequence_state *st, double d[3]) {
  double az = st->azimuth_deg * RP__SEQ_PI / 180.0;
  double el = st->elevation_deg * RP__SEQ_PI / 180.0;
  d[0] = cos(el) * sin(az);
  d[1] = sin(el);
  d[2] = cos(el) * cos(az);
}

static double ratio_apart(double a, double b) {
  return a > b ? a / b : b / a;
}

/* The camera jumps from `a` to `b` rather than moves
 * (RP_SEQUENCE_CUT_*). The angle is atan2(|a x b|, a . b), exact for
 * small and large turns alike. */
static int camera_jumps(const rp_sequence_state *a,
                        const rp_sequence_state *b) {
  double da[3], db[3], c[3], angle;
  view_dir(a, da);
  view_dir(b, db);
  c[0] = da[1] * db[2] - da[2] * db[1];
  c[1] = da[2] * db[0] - da[0] * db[2];
  c[2] = da[0] * db[1] - da[1] * db[0];
  angle = atan2(sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]),
                da[0] * db[0] + da[1] * db[1] + da[2] * db[2]) *
          180.0 / RP__SEQ_PI;
  return angle > RP_SEQUENCE_CUT_ANGLE_DEG ||
         ratio_apart(a->distance, b->distance) > RP_SEQUENCE_CUT_RATIO ||
         ratio_apart(a->fov_y_deg, b->fov_y_deg) > RP_SEQUENCE_CUT_RATIO ||
         hypot(a->pan[0] - b->pan[0], a->pan[1] - b->pan[1]) >
             RP_SEQUENCE_CUT_PAN;
}

int rp_sequence_frame(const rp_sequence *s, uint32_t i,
                      rp_sequence_state *st) {
  rp_sequence_state cur, prev;
  if (s == NULL || st == NULL)
    return s != NULL ? rp__fail(s->ctx, RP_EINVAL, "rp_sequence_frame: st "
                                "is required")
                     : RP_EINVAL;
  if (i >= s->frames)
    return rp__fail(s->ctx, RP_ERANGE, "sequence '%s': frame %u does not "
                    "exist (frames 0 to %u)", s->name, i, s->frames - 1);
  resolve(s, i, &cur);
  if (i == 0) {
    cur.camera_changed = cur.tf_changed = 1;
    cur.target_changed = cur.effects_changed = 1;
    cur.camera_cut = 0;
  } else {
    resolve(s, i - 1, &prev);
    cur.camera_changed = cur.azimuth_deg != prev.azimuth_deg ||
                         cur.elevation_deg != prev.elevation_deg ||
                         cur.distance != prev.distance ||
                         cur.pan[0] != prev.pan[0] ||
                         cur.pan[1] != prev.pan[1] ||
                         cur.fov_y_deg != prev.fov_y_deg;
    /* A marked cut that repeats the camera moves nothing: no cut. */
    cur.camera_cut = cur.camera_changed &&
                     (cur.camera_cut || camera_jumps(&prev, &cur));
    cur.tf_changed = cur.tf != prev.tf;
    cur.target_changed = cur.target_ms != prev.target_ms ||
                         cur.target_fraction != prev.target_fraction;
    cur.effects_changed = cur.effects != prev.effects;
  }
  *st = cur;
  return 0;
}

/* ---- Cameras ------------------------------------------------------------- */

static double norm3(const double v[3]) {
  return sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
}

static void cross(const double a[3], const double b[3], double out[3]) {
  out[0] = a[1] * b[2] - a[2] * b[1];
  out[1] = a[2] * b[0] - a[0] * b[2];
  out[2] = a[0] * b[1] - a[1] * b[0];
}

void rp_sequence_camera(const rp_sequence_state *st, const rp_volume *vol,
                        rp_camera *cam) {
  double radius = 0.0, f[3], up[3] = {0.0, 1.0, 0.0}, r[3], u[3], len;
  rp_volume_info info;
  int a;
  if (st == NULL || vol == NULL || cam == NULL)
    return;
  rp_volume_get_info(vol, &info);
  memset(cam, 0, sizeof *cam);
  cam->projection = st->projection;
  cam->fov_y_deg = (float)st->fov_y_deg;
  rp_camera_orbit(cam, vol, (float)st->azimuth_deg,
                  (float)st->elevation_deg, (float)st->distance);
  for (a = 0; a < 3; a++) {
    double e = (double)info.dims[a] * info.spacing[a];
    radius += e * e;
  }
  radius = 0.5 * sqrt(radius); /* as rp_camera_orbit measures it */
  if (st->projection == RP_ORTHOGRAPHIC)
    cam->ortho_height = (float)(2.0 * st->distance * radius *
                                tan(0.5 * st->fov_y_deg * RP__SEQ_PI /
                                    180.0));
  if (st->pan[0] == 0.0 && st->pan[1] == 0.0)
    return;
  /* The basis rp__raygen_init builds: right = f x up, up' = right x f,
   * with rp_camera_orbit's up (the way elevation rises; +y, or +z when f
   * is parallel to y, were it zero). Pan moves eye and centre together,
   * so f and this basis do not change. */
  for (a = 0; a < 3; a++)
    up[a] = (double)cam->up[a];
  if (norm3(up) == 0.0)
    up[1] = 1.0;
  for (a = 0; a < 3; a++)
    f[a] = -(double)cam->eye[a];
  len = norm3(f);
  if (len == 0.0) {
    f[0] = f[1] = 0.0;
    f[2] = -1.0;
  } else {
    for (a = 0; a < 3; a++)
      f[a] /= len;
  }
  cross(f, up, r);
  if (norm3(r) <= RP__PARALLEL_EPS) {
    up[1] = 0.0;
    up[2] = 1.0;
    cross(f, up, r);
  }
  len = norm3(r);
  for (a = 0; a < 3; a++)
    r[a] /= len;
  cross(r, f, u);
  for (a = 0; a < 3; a++) {
    double shift = (st->pan[0] * r[a] + st->pan[1] * u[a]) * radius;
    cam->eye[a] = (float)(cam->eye[a] + shift);
    cam->center[a] = (float)shift;
  }
}
