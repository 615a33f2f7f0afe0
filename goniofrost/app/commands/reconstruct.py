"""goniofrost reconstruct: samples (SAMPLES.csv) -> full BRDF as a MERL .binary, with its uncertainty.

Default (``--estimator bayes``): the posterior mean over all model atoms. Beside OUT it writes
``OUT.std.binary`` (the MERL layout: per cell and channel the predictive standard deviation of
ln(w x + eps), dimensionless, w = clip(cos theta_i cos theta_o, 0.01, 1), eps = 0.001) and
``OUT.json`` (the predicted log-relative MSE, how the reconstruction was made, and whether the
prediction is an extrapolation: ``extrapolation``, ``out_of_model``, ``design``).
docs/reference/file-formats.md describes both files.
"""
from __future__ import annotations

HELP = ("reconstruct a full BRDF from samples (Bayesian posterior mean with per-cell uncertainty, "
        "or the paper's ridge regression)")


def add_arguments(parser) -> None:
    parser.add_argument("--model", required=True, metavar="MODEL", help="model directory from goniofrost train")
    parser.add_argument("--samples", required=True, metavar="SAMPLES.csv",
                        help="header theta_h_deg,theta_d_deg,phi_d_deg,r,g,b (1/sr); extra columns allowed; "
                             "sigma_r,sigma_g,sigma_b (standard deviations, 1/sr) are used when present")
    parser.add_argument("--estimator", choices=("bayes", "ridge"), default="bayes",
                        help="bayes (default): posterior mean over all atoms with the model's noise, writes "
                             "OUT.std.binary and OUT.json; ridge: the paper's ridge regression (--eta, --atoms)")
    parser.add_argument("--eta", type=float, default=None, help="ridge only: ridge weight (default 40, the published setting)")
    parser.add_argument("--atoms", type=int, metavar="A",
                        help="ridge only: atoms used (default min(distinct sampled cells, model components))")
    parser.add_argument("--out", required=True, metavar="FILE.binary",
                        help="MERL file to write, ending in .binary (with --estimator bayes, FILE.std.binary and "
                             "FILE.json go beside it)")


def run(args) -> int:
    from goniofrost.brdf.merl_file import valid_to_full, write_merl
    from goniofrost.core.atomic_file import (check_not_an_input, check_output_file, check_output_folder_exists,
                                             check_output_suffix)
    from goniofrost.core.errors import GoniofrostError
    from goniofrost.frost.model import FrostModel
    from goniofrost.frost.outputs import bayes_output_paths
    from goniofrost.frost.reconstruction import ETA, reconstruct
    from goniofrost.frost.samples_file import read_samples_csv, sample_sigmas

    # before the model is read: --out brdf.txt held a MERL file, and --out brdf wrote brdf,
    # brdf.std.binary and brdf.json (the side files' names are OUT's with .binary replaced)
    check_output_suffix(args.out, ".binary", "the file is written in MERL's .binary format")
    check_output_folder_exists(args.out)  # a mistyped folder was made, silently
    outputs = [args.out] + (list(bayes_output_paths(args.out)) if args.estimator == "bayes" else [])
    for out in outputs:  # reconstruct --out s.csv overwrote the samples it read with the BRDF
        check_not_an_input(out, {"--samples": args.samples, "--model": args.model})
        # a folder in the place of any of the three, before one is written: a folder named OUT.json
        # was refused only after OUT and OUT.std.binary were written (exit 2, two of the three
        # files); a folder the three share that cannot be written, after the reconstruction
        check_output_file(out)
    model = FrostModel.load(args.model)
    cells, values, extra = read_samples_csv(args.samples, model.grid)
    positions = model.grid.valid_position(cells)
    if args.estimator == "ridge":
        brdf = reconstruct(model, positions, values, eta=ETA if args.eta is None else args.eta, n_atoms=args.atoms)
        write_merl(args.out, valid_to_full(brdf, model.grid), model.grid)
        print(f"{args.out}: reconstructed from {cells.size} samples (ridge)")
        return 0
    if args.eta is not None or args.atoms is not None:
        raise GoniofrostError("--eta and --atoms apply to --estimator ridge only")
    from goniofrost.frost.confidence import extrapolation_fields, extrapolation_lines, figure_of
    from goniofrost.frost.outputs import write_bayes_outputs
    from goniofrost.frost.reconstruction import error_bound, reconstruct_bayes

    sigmas = sample_sigmas(args.samples, extra)
    rec = reconstruct_bayes(model, positions, values, sigmas=sigmas)
    bound = error_bound(model, positions, values, sigmas)  # its flags: is the prediction an extrapolation?
    std_path, record_path = write_bayes_outputs(args.out, model, rec, args.samples, bound)
    print(f"{args.out}: reconstructed from {cells.size} samples ({rec.samples} cells; Bayesian posterior mean)")
    print(f"log-relative MSE: {figure_of(bound)}"
          + (" (an extrapolation)" if bound.out_of_model else "")
          + f"; per-cell standard deviation in {std_path}; record in {record_path}")
    for line in extrapolation_lines(extrapolation_fields(bound)):
        print(line)
    return 0
