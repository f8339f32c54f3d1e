/* The controller block's state (see glue.h): its discrete states and how many samples it has taken. */
#ifndef CEDRA_CONTROLLER_H
#define CEDRA_CONTROLLER_H

typedef struct {
    double xd[CEDRA_ND > 0 ? CEDRA_ND : 1];   /* discrete states (e.g. the PI integrators) after the last sample */
    long taken;                               /* samples taken: sample k is at start_time + k * period */
} block_state;

#endif
