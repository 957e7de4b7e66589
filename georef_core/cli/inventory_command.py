"""`georef inventory SITE_DIR --date D`: every stockpile of a site folder's registry (stockpiles.json, as
`georef stockpile` keeps it) at a date: volume, tonnes and change since the last survey, with their
uncertainty, as a table, CSV, XLSX or JSON (georef_core/deliverables/inventory.py)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from ..errors import GeorefError


def register(sub) -> None:
    p = sub.add_parser("inventory", help="all stockpiles of a site at a date: volume, tonnes, change, +- uncertainty",
                       description="The latest survey on or before DATE of every pile of SITE_DIR/stockpiles.json.")
    p.add_argument("site_dir", help="site folder holding stockpiles.json (georef stockpile)")
    p.add_argument("--date", required=True, help="YYYY-MM-DD: the inventory date")
    p.add_argument("--out", help="write FILE.csv or FILE.xlsx")
    p.add_argument("--json", action="store_true", help="print the inventory as JSON")
    p.add_argument("--density", action="append", default=[], metavar="NAME=RHO[+-SIGMA]",
                   help="density (t/m3) of a pile or a material, e.g. 'Sand=1.62+-0.05' (repeatable; a pile's name "
                        "wins over its material)")
    p.set_defaults(func=cmd_inventory)


def _densities(items: list[str]) -> dict[str, tuple[float, float | None]]:
    out = {}
    for it in items:
        name, _, val = it.partition("=")
        rho, _, sig = val.replace("±", "+-").partition("+-")
        try:
            out[name.strip()] = (float(rho), float(sig) if sig else None)
        except ValueError:
            raise GeorefError(f"--density {it!r}: expected NAME=RHO or NAME=RHO+-SIGMA (t/m3)") from None
        if not name.strip() or out[name.strip()][0] <= 0:
            raise GeorefError(f"--density {it!r}: a name and a positive density are needed")
    return out


def cmd_inventory(args) -> int:
    from datetime import date

    from ..deliverables.inventory import build_inventory, material_key, piles_from_registry, to_csv, to_xlsx
    from ..volumes.stockpile_records import StockpileRegistry

    try:
        day = date.fromisoformat(args.date)
    except ValueError:
        raise GeorefError(f"--date {args.date!r}: expected YYYY-MM-DD") from None
    reg = StockpileRegistry.load(args.site_dir)
    if not reg.records:
        raise GeorefError(f"no stockpiles in {reg.path}; add them with 'georef stockpile {args.site_dir} add'")
    piles = piles_from_registry(reg)
    given = _densities(args.density)
    by_material = {material_key(k): v for k, v in given.items()}
    for p in piles:
        d = given.get(p.name) or by_material.get(material_key(p.material))
        if d:
            p.density_t_m3, p.density_sigma_t_m3 = d
    inv = build_inventory(piles, day)
    if args.out:
        out = Path(args.out)
        if out.suffix.lower() == ".csv":
            out.write_bytes(to_csv(inv))
        elif out.suffix.lower() == ".xlsx":
            out.write_bytes(to_xlsx(inv, {"site folder": str(Path(args.site_dir).resolve())}))
        else:
            raise GeorefError(f"--out {args.out}: .csv or .xlsx")
        print(f"inventory of {len(inv.rows)} pile(s) at {day} written to {out}", file=sys.stderr)
    if args.json:
        json.dump(inv.as_dict(), sys.stdout, indent=1)
        print()
    elif not args.out:
        def f(v, nd=1):
            return "-" if v is None else f"{v:,.{nd}f}"
        print(f"Stockpile inventory at {day} ({reg.path})")
        print(f"{'pile':<16} {'survey date':<11} {'volume m3':>11} {'±1σ':>7} {'t/m3':>5} {'tonnes t':>11} {'±1σ':>7} "
              f"{'change m3':>10} {'±1σ':>7}")
        for r in inv.rows + [inv.totals]:
            print(f"{r['stockpile'][:16]:<16} {r['survey_date'] or '-':<11} {f(r['volume_m3']):>11} "
                  f"{f(r['volume_sigma_m3']):>7} {f(r['density_t_m3'], 2):>5} {f(r['tonnes_t']):>11} "
                  f"{f(r['tonnes_sigma_t']):>7} {f(r['change_m3']):>10} {f(r['change_sigma_m3']):>7}")
    return 0
