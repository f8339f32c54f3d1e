"""Dynamics optimization of a climb (`python -m cedra optimize`, docs/optimize.md): the wheel torques that take
the planar rover over an obstacle at the least cost, on the very equations the scene's FMU integrates, by direct
multiple shooting and IPOPT, replayed open loop through the FMU. The modules, from the bottom up:

  problem         the problem file: keys, defaults, checks
  dynamics        the optimizer's equations from the model's (the smoothed contact law a free width)
  numpy_function  numpy code as CasADi functions, for nlpsol's oracles
  shooting        multiple shooting, the lifted transcription (every state a node decision), its Hessians
  carried_spin    the transcription that carries the wheels' spin rates through the intervals
  nlp             the optimal control problem for IPOPT, the continuation over smoothing widths
  fmu_runs        the controllers' runs (the guess, the comparison), the replay, the measures
  report          result.json, torques.csv, climb.png, report.md
  command         the command: all of the above in order"""
from cedra.optimize.carried_spin import CarriedSpinHessian, CarriedSpinShooting
from cedra.optimize.command import add_parser, main, run
from cedra.optimize.dynamics import Dynamics, goal, model_path, state_bounds
from cedra.optimize.fmu_runs import controller_run, initial_guess, measures, replay
from cedra.optimize.numpy_function import NumpyFunction
from cedra.optimize.problem import GUESSES, OBJECTIVES, Problem, ProblemError, load, parse
from cedra.optimize.report import report_text
from cedra.optimize.shooting import ShootingHessian, interval_jacobian, mapped
from cedra.optimize.nlp import continuation, solve

__all__ = ["CarriedSpinHessian", "CarriedSpinShooting", "Dynamics", "GUESSES", "NumpyFunction", "OBJECTIVES",
           "Problem", "ProblemError", "ShootingHessian", "add_parser", "continuation", "controller_run", "goal",
           "initial_guess", "interval_jacobian", "load", "main", "mapped", "measures", "model_path", "parse", "replay",
           "report_text", "run", "solve", "state_bounds"]
