"""goniofrost reconstruct: samples (SAMPLES.csv) -> full BRDF as a MERL .binary."""
from __future__ import annotations

HELP = "reconstruct a full BRDF from samples (ridge regression on the FROST dictionary)"


def add_arguments(parser) -> None:
    parser.add_argument("--model", required=True, metavar="MODEL", help="model directory from goniofrost train")
    parser.add_argument("--samples", required=True, metavar="SAMPLES.csv",
                        help="header theta_h_deg,theta_d_deg,phi_d_deg,r,g,b (1/sr); extra columns allowed")
    parser.add_argument("--eta", type=float, default=40.0, help="ridge weight (default 40, the published setting)")
    parser.add_argument("--atoms", type=int, metavar="A",
                        help="atoms used (default min(distinct sampled cells, model components))")
    parser.add_argument("--out", required=True, metavar="FILE.binary", help="MERL .binary to write")


def run(args) -> int:
    from goniofrost.brdf.merl_file import valid_to_full, write_merl
    from goniofrost.frost.model import FrostModel
    from goniofrost.frost.reconstruction import read_samples_csv, reconstruct

    model = FrostModel.load(args.model)
    cells, values, _ = read_samples_csv(args.samples, model.grid)
    brdf = reconstruct(model, model.grid.valid_position(cells), values, eta=args.eta, n_atoms=args.atoms)
    write_merl(args.out, valid_to_full(brdf, model.grid), model.grid)
    print(f"{args.out}: reconstructed from {cells.size} samples")
    return 0
