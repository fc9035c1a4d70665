/* Subcommands of the raypace command that live in their own files. Each
 * takes argv with argv[0] = the subcommand's name and returns the exit
 * status. */
#ifndef RP_CLI_COMMANDS_H
#define RP_CLI_COMMANDS_H

/* raypace replay VOLUME ...: cli/replay.c */
int cli_cmd_replay(int argc, char **argv);
/* raypace bench quality VOLUME ...: cli/bench.c */
int cli_cmd_bench(int argc, char **argv);
/* raypace bench overhead VOLUME ...: cli/bench_overhead.c */
int cli_cmd_bench_overhead(int argc, char **argv);

#endif
