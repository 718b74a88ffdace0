"""Training verbs: train (phase 1 or 2), export (the inference part of a run) and rollouts (phase 2's bank)."""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

from hyperbones.cli import options
from hyperbones.errors import InputFileError, ParameterError


def run_train(args) -> int:
    from hyperbones.training.config import HyperBonesTrainingConfig, apply_overrides, load_config
    from hyperbones.training.joint import JointTrainer
    from hyperbones.training.trainer import TeacherTrainer, train_to_end

    config = apply_overrides(load_config(args.config), args.set)
    kind = JointTrainer if isinstance(config, HyperBonesTrainingConfig) else TeacherTrainer
    trainer = kind(config, args.out, resume=args.resume, progress=not args.quiet, max_steps=args.max_steps)
    step = train_to_end(trainer)
    if trainer.is_main:
        print(f"trained to step {step}; checkpoint {trainer.checkpoint_path.resolve()}, "
              f"TensorBoard logs {(trainer.run_dir / 'tensorboard').resolve()}")
    return 0


def add_train(sub) -> None:
    train = sub.add_parser("train", help="train the teacher (phase 1) or all of HyperBones (phase 2), self-supervised",
                           description="Trains from a TOML config. A config with [model], [data], [train] trains the "
                                       "teacher (Module C) on the physics energies (configs/teacher*.toml; under "
                                       "torchrun on every process, DDP); one that also has [runtime] and [joint] "
                                       "trains Modules A, B and C together from a teacher run "
                                       "(configs/hyperbones*.toml, one process). Writes OUT/checkpoint.pt (atomic, "
                                       "every train.checkpoint_every steps, config inside) and TensorBoard logs in "
                                       "OUT/tensorboard. Every field is documented in hyperbones.training.config.")
    train.add_argument("--config", required=True, help="TOML training config")
    options.add_set(train)
    options.add_out(train, "run folder")
    train.add_argument("--resume", action="store_true", help="continue the run in --out from its checkpoint")
    train.add_argument("--max-steps", type=int, default=None, help="stop at this step (below train.steps)")
    options.add_quiet(train)
    train.set_defaults(func=run_train)


def run_export(args) -> int:
    from hyperbones.io_utils import staged_outputs
    from hyperbones.training.checkpoint import export_weights

    out = Path(args.out)
    summary = Path(args.summary) if args.summary else out.with_suffix(".md")
    if args.share_teacher and not (out.parent / "teacher.pt").is_file():
        raise ParameterError(f"--share-teacher: no teacher.pt beside {out} to read the teacher from")
    runtime = {"runtime_from": args.runtime_from, "runtime": args.runtime, "summary_from": args.summary_from}
    # The weights and their summary appear together or not at all (each folder's set is staged).
    with staged_outputs(out.parent) as staging:
        if summary.parent.resolve() == out.parent.resolve():
            export_weights(args.checkpoint, staging / out.name, summary=staging / summary.name, **runtime)
        else:
            with staged_outputs(summary.parent) as summary_staging:
                export_weights(args.checkpoint, staging / out.name, summary=summary_staging / summary.name, **runtime)
        if args.share_teacher:
            from hyperbones.models.loading import load_checkpoint, save_checkpoint, without_teacher

            save_checkpoint(staging / out.name, without_teacher(load_checkpoint(staging / out.name),
                                                                out.parent / "teacher.pt"))
    print(f"wrote {out.resolve()} and {summary.resolve()}")
    return 0


def add_export(sub) -> None:
    export = sub.add_parser("export", aliases=["export-teacher"],
                            help="keep only what inference needs from a training checkpoint (teacher or HyperBones)",
                            description="Writes OUT (the weights' moving average + config + step, and for a "
                                        "HyperBones model its RuntimeConfig; loads with weights_only) and OUT with "
                                        ".md: the config, training wall time and a summary of the run's TensorBoard "
                                        "log up to the checkpoint's step. Given an exported HyperBones model "
                                        "instead, it writes the same weights with other runtime settings "
                                        "(--runtime), carrying the training record of its summary over.")
    export.add_argument("checkpoint", help="a run's checkpoint.pt, or an exported model to store other runtime "
                                           "settings with (its weights unchanged)")
    options.add_out(export, "output .pt (model weights + config)")
    export.add_argument("--summary", default=None,
                        help="where to write the .md summary (default: beside --out; the shipped models' are in "
                             "docs/checkpoints/)")
    export.add_argument("--summary-from", default=None, metavar="MD",
                        help="an exported model as CHECKPOINT: its summary, whose training record is carried into "
                             "the new one (default: CHECKPOINT with .md, when it exists; the shipped models' are in "
                             "docs/checkpoints/)")
    export.add_argument("--share-teacher", action="store_true",
                        help="a HyperBones model: store its teacher as read from the teacher.pt beside --out, "
                             "which must hold the same weights bit for bit, not as a copy (how the shipped "
                             "hyperbones.pt is saved; the two files then travel together)")
    export.add_argument("--runtime-from", default=None, metavar="MODEL.pt|defaults",
                        help="a HyperBones model: store the runtime settings of this exported model ('defaults': "
                             "RuntimeConfig's own) (default: the checkpoint's, else the shipped model's, so a new "
                             "model runs and measures as the shipped one does)")
    export.add_argument("--runtime", default=None, metavar="KEY=VALUE,...",
                        help="a HyperBones model: settings over those, e.g. 'proxy_vertices=0' (the keys are the "
                             "fields of hyperbones.runtime.config.RuntimeConfig)")
    export.set_defaults(func=run_export)


def run_rollouts(args) -> int:
    from hyperbones.training.config import HyperBonesTrainingConfig, load_config
    from hyperbones.training.rollouts import generate_bank

    config = load_config(args.config)
    if not isinstance(config, HyperBonesTrainingConfig):
        raise InputFileError(args.config, "not a HyperBones (phase 2) config: it has no [joint] table")
    out = args.out or config.joint.bank
    if not out:
        raise ParameterError("no --out, and the config's joint.bank is empty")
    if args.templates:
        templates = tuple(options.comma_list(args.templates))
        unknown = sorted(set(templates) - set(config.data.templates))
        if unknown:
            raise ParameterError(f"--templates {', '.join(unknown)}: not among the config's data.templates "
                                 f"({', '.join(config.data.templates)})")
        config = replace(config, data=replace(config.data, templates=templates))
    if args.drape is not None:
        config = replace(config, data=replace(config.data, drape=args.drape))
    generate_bank(config, out, args.count, seed=args.seed, progress=not args.quiet, compile_teacher=args.compile,
                  bfloat16=args.bfloat16)
    return 0


def add_rollouts(sub) -> None:
    rollouts = sub.add_parser("rollouts", help="simulate teacher rollouts into a bank for phase 2 (joint.bank)",
                              description="Rolls the config's teacher (train.init_from) out over random training "
                                          "identities and clip windows, as phase 2's cache does, and saves each "
                                          "rollout (~1 MB) to the bank folder. Several processes with different "
                                          "--seed values can fill one bank; the same seed goes on where it stopped.")
    rollouts.add_argument("--config", required=True, help="HyperBones (phase 2) TOML config")
    rollouts.add_argument("--out", default=None, help="bank folder (default: the config's joint.bank)")
    rollouts.add_argument("--count", type=int, default=100, help="rollouts to add (default: 100)")
    rollouts.add_argument("--seed", type=int, default=0, help="draw seed; one per process sharing a bank (default: 0)")
    rollouts.add_argument("--templates", default=None,
                          help="comma list: draw only these of the config's garment templates (default: all), "
                               "to add rollouts of garments the model does worst on")
    rollouts.add_argument("--drape", action=argparse.BooleanOptionalAction, default=None,
                          help="start every rollout from its garment draped on the body, as simulate does "
                               "(--no-drape: from the garment carried to the body, skipping the drape's 15 s to 2.5 min "
                               "of one core); default: the config's data.drape. A bank may mix draped and carried starts, "
                               "and training rebuilds each as it was")
    rollouts.add_argument("--compile", action="store_true",
                          help="compile the teacher's network (torch.compile): ~1.2-1.35x faster rollouts on the CPU "
                               "after 10-30 s of compiling, for a long bank; needs a C++ compiler (gcc or clang)")
    rollouts.add_argument("--bfloat16", action="store_true",
                          help="run the teacher's network in bfloat16 (autocast; the physics stays float32): with "
                               "--compile ~1.25x faster rollouts on CPUs with bfloat16 units (AVX512-BF16, AMX), "
                               "slower on others (a warning says so)")
    options.add_quiet(rollouts)
    rollouts.set_defaults(func=run_rollouts)


def run_pack(args) -> int:
    from hyperbones.training.config import apply_overrides, load_config
    from hyperbones.training.pack import QUICK_BODIES, QUICK_DATA, build_pack

    config = apply_overrides(load_config(args.config), [*(QUICK_DATA if args.quick else ()), *(args.set or ())])
    summary = build_pack(config, args.out, bodies=QUICK_BODIES if args.quick else args.bodies, seed=args.seed,
                         progress=None if args.quiet else (lambda text: print(f"packing {text}", flush=True)))
    print(f"wrote {Path(args.out).resolve()} ({summary['bytes'] / 2**20:.1f} MiB): {summary['bodies']} training "
          f"bodies (PCA basis {summary['basis']}, largest rebuild error {summary['body_error_m'] * 1e3:.3f} mm), "
          f"{summary['templates']} garments, {summary['motions']} motions ({summary['frames']} frames)")
    return 0


def add_pack(sub) -> None:
    pack = sub.add_parser("pack", help="write a training pack: what training needs from Anny, Warp and the drape",
                          description="Writes one file holding the config's training bodies (PCA-compressed), "
                                      "garment templates with their skinning, carrying binding and (for a phase-2 "
                                      "config) virtual bones, the retargeted training motions and the fabric "
                                      "ranges, so `python -m hyperbones.training.from_pack` can train where only "
                                      "torch is installed (a GPU machine). See the README, \"Training on a GPU\".")
    pack.add_argument("--config", required=True, help="TOML training config (teacher or phase 2)")
    options.add_set(pack)
    options.add_out(pack, "pack file (.pt)")
    pack.add_argument("--bodies", type=int, default=256,
                      help="training body shapes to draw, away from the held-out bodies (default: 256)")
    pack.add_argument("--seed", type=int, default=0, help="seed of the body draw (default: 0)")
    pack.add_argument("--quick", action="store_true",
                      help="a small pack for checks: 2 bodies, the tshirt at 1k vertices, one clip and the walk "
                           "(train it with the pack trainer's --quick)")
    options.add_quiet(pack)
    pack.set_defaults(func=run_pack)


VERBS = (add_train, add_export, add_rollouts, add_pack)
