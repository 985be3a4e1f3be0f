"""The printer profile's schema: one frozen dataclass per YAML section, whose field
metadata gives each key's type, bounds and default (read by
:func:`pipeline.profiles.profile.parse_profile`; documented in ``profiles/README.md``),
and the validated :class:`Profile` with what it renders into G-code."""

from dataclasses import MISSING, dataclass, field

from pipeline.profiles.shrink import ShrinkCurve

# The line before `gcode.clear_bed` in a plan's G-code: a finished print whose file has it
# (and no other) leaves its bed clear by itself.
CLEAR_BED_MARK = "; hostd clear_bed: the part leaves the bed by itself"

# Placeholders the G-code templates may use; values come from Profile.gcode_vars().
GCODE_PLACEHOLDERS = ("hotend_c", "bed_c", "bed_x_mm", "bed_y_mm", "max_z_mm", "nozzle_mm",
                      "filament_mm", "path_width_mm", "retract_mm", "retract_f", "z_hop_mm",
                      "travel_f", "print_f", "first_layer_f", "e_mode")


def _num(default=MISSING, lo=0.0, strict=True, hi=None, integer=False, nullable=False):
    """A numeric field: ``lo < v`` (``lo <= v`` if not strict), ``v <= hi``; with
    ``nullable``, also null (None), which the field's reader gives a meaning."""
    kind = "int" if integer else "float"
    return field(default=default, metadata={"kind": kind, "lo": lo, "strict": strict, "hi": hi,
                                            "nullable": nullable})


def _str(default=MISSING, choices=None, multiline=False):
    return field(default=default, metadata={"kind": "str", "choices": choices,
                                            "multiline": multiline})


def _section(cls):
    return field(default_factory=cls, metadata={"kind": "section", "cls": cls})


@dataclass(frozen=True)
class ThicknessRange:
    """Allowed layer thickness range, mm."""
    min: float = _num()
    max: float = _num()


@dataclass(frozen=True)
class ShrinkLimits:
    """Usable shrink ratio range for flattening (sigma = 1 - target/flat length)."""
    s_min: float = _num(0.0, lo=0.0, strict=False, hi=0.99)
    s_max: float = _num(0.343, lo=0.0, hi=0.99)


@dataclass(frozen=True)
class Speeds:
    """Feed rates, mm/s."""
    print: float = _num(50.0)
    first_layer: float = _num(30.0)
    travel: float = _num(150.0)


@dataclass(frozen=True)
class Temperatures:
    """Set points, degrees C (0 = heater off / not present)."""
    hotend: float = _num(215.0, strict=False, hi=350.0)
    bed: float = _num(60.0, strict=False, hi=150.0)


@dataclass(frozen=True)
class Retraction:
    length_mm: float = _num(0.8, strict=False, hi=20.0)
    speed_mm_s: float = _num(35.0)
    z_hop_mm: float = _num(0.4, strict=False, hi=10.0)


@dataclass(frozen=True)
class Serial:
    port: str = _str("/dev/ttyUSB0")
    baud: int = _num(115200, integer=True)


@dataclass(frozen=True)
class GcodeTemplates:
    """Multi-line G-code snippets; may use the placeholders in GCODE_PLACEHOLDERS."""
    start: str = _str("G28\nM104 S{hotend_c}\nM140 S{bed_c}\nM190 S{bed_c}\nM109 S{hotend_c}\n",
                      multiline=True)
    end: str = _str("M83\nG1 E-{retract_mm} F{retract_f}\nM104 S0\nM140 S0\nG91\nG1 Z10 F600\n"
                    "G90\nM84\n", multiline=True)
    cancel: str = _str("M104 S0\nM140 S0\nM107\nG91\nG1 Z10 F600\nG90\nM84\n", multiline=True)
    pause: str = _str("G91\nG1 Z10 F600\nG90\n", multiline=True)
    resume: str = _str("G91\nG1 Z-10 F600\nG90\n{e_mode}\n", multiline=True)
    # Run at the end of every finished print when `bed_clear: auto`: the moves that take
    # the part off the bed by themselves (a belt, a sweep of the gantry).
    clear_bed: str = _str("", multiline=True)


@dataclass(frozen=True)
class MeshParams:
    isoline_step_mm: float = _num(1.0)
    gradient_spacing_mm: float = _num(2.0)
    l_u_mm: float = _num(0.25)
    min_prominence_mm: float = _num(2.0, strict=False)
    smooth_mm: float = _num(1.0, strict=False)
    l_sim_mm: float = _num(2.0, strict=False)
    # The free method's mesh. At 1.25 mm the sheet ends as close to the file as at 1 mm and
    # forms the same relief at 2-8 mm (the benchmark's models), and a 175 mm plan costs
    # 40 % less time.
    grid_mm: float = _num(1.25)


@dataclass(frozen=True)
class FlattenParams:
    """The layout method; projective-dynamics iterations and constraint weights of the
    isoline method (paper 6.2 defaults); local/global iterations of the free one."""
    method: str = _str("free", choices=("isoline", "free"))
    iterations: int = _num(50, integer=True)
    free_iterations: int = _num(50, integer=True)
    # How the plan checks an isoline layout: the paper's projective dynamics, or the
    # thin shell the free method uses (printed thickness, converges under refinement).
    simulation: str = _str("paper", choices=("paper", "shell"))
    # How the fit smooths a relief the sheet cannot form: the whole field as much as its
    # worst spot needs (global), or only where it does not form, blended (local).
    fit_smoothing: str = _str("global", choices=("global", "local"))
    w_bridge: float = _num(1.0, strict=False)
    w_printing: float = _num(1.0, strict=False)
    w_bending: float = _num(0.025, strict=False)
    w_shear: float = _num(0.25, strict=False)
    w_flattening: float = _num(0.3, strict=False)
    w_stretching: float = _num(1.0, strict=False)
    w_spreading: float = _num(0.5, strict=False)

    def weights(self):
        """The isoline layout's constraint weights, by the names the solver knows them."""
        return {"bridge": self.w_bridge, "printing": self.w_printing,
                "bending": self.w_bending, "shear": self.w_shear,
                "flattening": self.w_flattening, "stretching": self.w_stretching,
                "spreading": self.w_spreading}


@dataclass(frozen=True)
class ToolpathParams:
    merge_angle_deg: float = _num(2.0, strict=False, hi=45.0)
    merge_sigma: float = _num(0.005, strict=False, hi=1.0)
    arc_tolerance_mm: float = _num(0.0, strict=False)
    chord_tolerance_mm: float = _num(0.02, strict=False, hi=1.0)
    # The longest hop joining two stripe pieces into one trace, in path widths, and how
    # far it may run over printed paths (third ones, or back over its own two away from
    # their ends); where it runs over them for two widths or more it moves dry. At 40
    # widths (19 mm at 0.48 mm) a dry hop, at the travel speed, takes less time than a
    # retraction, a lift and a travel would. Lower layers on the real tiles at 175 mm,
    # traces a layer: reach 9, over 8: 33 and 24; 25 and 40: 1 and 1; on the saddle and
    # the elongated peak 25: 3 and 2, 40: 1 and 1.
    hop_reach_widths: float = _num(40.0, strict=False, hi=100.0)
    hop_over_widths: float = _num(40.0, strict=False, hi=100.0)
    # An end at the sheet's edge joins the path beside it, that path's tail along the
    # edge left out, where the tail is no longer than this many path widths (0: never).
    rim_tail_widths: float = _num(20.0, strict=False, hi=100.0)


@dataclass(frozen=True)
class CurvatureParams:
    """The bilayer's constant: ``kappa = bilayer_c * (sigma_bottom - sigma_top) / h``, and
    the layers across the paths' (:mod:`pipeline.layout.laminate`)."""
    # Timoshenko's bilayer of two equal layers of one material; `hostd calibrate
    # bilayer-fit` measures the printer's own and marks it `measured`.
    bilayer_c: float = _num(1.5, hi=20.0)
    status: str = _str("uncalibrated", choices=("uncalibrated", "measured"))
    # How far each layer group may turn off the print direction to program the
    # target's twist (0: both print along it). 20 and 40 degrees measured alike.
    turn_max_deg: float = _num(20.0, strict=False, hi=45.0)
    # Shrink the program may add along the print direction where the layout leaves too
    # little around the mean for the thickness difference the curvature wants (0: none).
    max_added_shrink: float = _num(0.03, strict=False, hi=0.2)
    # Two layers printed across the paths to program the curvature across
    # them: `auto` tries it and keeps it where the sheet then rests closer, `off` never.
    across_layers: str = _str("auto", choices=("auto", "off"))
    # The constant of those two layers, which curl the sheet from inside the stack on
    # paths of their own: null until `hostd calibrate across-fit` measures it, and then
    # the bilayer's is the best guess (a measured `bilayer_c` carries over).
    across_c: float = _num(None, hi=20.0, nullable=True)
    across_status: str = _str("uncalibrated", choices=("uncalibrated", "measured"))
    # Where the plan smoothed the relief (the fit, or the smoothing that holds), the
    # program reads it smoothed only this share as much (1: the target as smoothed);
    # see :data:`pipeline.layout.curvature.PROGRAM_DETAIL`.
    program_smoothing: float = _num(0.5, hi=1.0)

    @property
    def across_constant(self):
        """The constant the layers across are programmed with: ``across_c``, else
        ``bilayer_c``."""
        return self.bilayer_c if self.across_c is None else self.across_c


@dataclass(frozen=True)
class PrintableLimits:
    """Within these a plan prints by itself; outside them it waits for a person (fractions)."""
    max_invalid_area: float = _num(0.25, strict=False, hi=1.0)
    max_mean_displacement: float = _num(0.03, strict=False, hi=1.0)
    min_coverage: float = _num(0.90, strict=False, hi=1.0)


@dataclass(frozen=True)
class ValidateParams:
    max_fill_mm: float = _num(2.0, strict=False)
    max_pixels: int = _num(25_000_000, integer=True)
    min_pixels: int = _num(16, lo=2, strict=False, integer=True)
    working_pixel_mm: float = _num(0.25, strict=False)


@dataclass(frozen=True)
class Defaults:
    """Physical scale for inputs without a sidecar."""
    size_mm: float = _num(150.0)
    height_mm: float = _num(30.0)


@dataclass(frozen=True)
class Profile:
    """A validated printer profile.

    ``shrink_curve`` is the fitted :class:`pipeline.profiles.shrink.ShrinkCurve` (its
    ``thickness_mm``, ``shrink`` and ``degree`` are the YAML's points and degree).
    ``source`` is the file it came from, ``raw`` the parsed YAML as written,
    ``warnings`` what was adjusted at load (e.g. s_max clamped to the curve).
    """

    name: str = _str()
    bed_mm: tuple = field(default=MISSING, metadata={"kind": "pair"})
    nozzle_mm: float = _num(hi=5.0)
    filament_mm: float = _num(hi=5.0)
    path_width_mm: float = _num(hi=5.0)
    layers: int = _num(lo=1, strict=False, integer=True)
    thickness_mm: ThicknessRange = field(default=MISSING,
                                         metadata={"kind": "section", "cls": ThicknessRange})
    shrink_curve: ShrinkCurve = field(default=MISSING, metadata={"kind": "curve"})
    description: str = _str("")
    max_z_mm: float = _num(200.0)
    filament_density_g_cm3: float = _num(1.24)
    shrink_limits: ShrinkLimits = _section(ShrinkLimits)
    speeds_mm_s: Speeds = _section(Speeds)
    temperatures_c: Temperatures = _section(Temperatures)
    retraction: Retraction = _section(Retraction)
    extrusion: str = _str("relative", choices=("relative", "absolute"))
    # Who clears the bed after a print: `person` (the printer waits until one says the bed
    # is clear) or `auto` (gcode.clear_bed takes the finished part off by itself).
    bed_clear: str = _str("person", choices=("person", "auto"))
    serial: Serial = _section(Serial)
    gcode: GcodeTemplates = _section(GcodeTemplates)
    mesh: MeshParams = _section(MeshParams)
    flatten: FlattenParams = _section(FlattenParams)
    toolpath: ToolpathParams = _section(ToolpathParams)
    printable: PrintableLimits = _section(PrintableLimits)
    curvature: CurvatureParams = _section(CurvatureParams)
    validate: ValidateParams = _section(ValidateParams)
    defaults: Defaults = _section(Defaults)
    source: str = field(default="", compare=False, metadata={"kind": None})
    raw: dict = field(default_factory=dict, compare=False, repr=False, metadata={"kind": None})
    warnings: tuple = field(default=(), compare=False, metadata={"kind": None})

    def gcode_vars(self):
        """Values for the G-code template placeholders (feed rates ``*_f`` in mm/min)."""
        return {"hotend_c": _fmt(self.temperatures_c.hotend), "bed_c": _fmt(self.temperatures_c.bed),
                "bed_x_mm": _fmt(self.bed_mm[0]), "bed_y_mm": _fmt(self.bed_mm[1]),
                "max_z_mm": _fmt(self.max_z_mm), "nozzle_mm": _fmt(self.nozzle_mm),
                "filament_mm": _fmt(self.filament_mm), "path_width_mm": _fmt(self.path_width_mm),
                "retract_mm": _fmt(self.retraction.length_mm),
                "retract_f": _fmt(60 * self.retraction.speed_mm_s),
                "z_hop_mm": _fmt(self.retraction.z_hop_mm),
                "travel_f": _fmt(60 * self.speeds_mm_s.travel),
                "print_f": _fmt(60 * self.speeds_mm_s.print),
                "first_layer_f": _fmt(60 * self.speeds_mm_s.first_layer),
                "e_mode": "M83" if self.extrusion == "relative" else "M82"}

    def render_gcode(self, which):
        """The ``gcode.<which>`` template with placeholders filled: str."""
        return getattr(self.gcode, which).format(**self.gcode_vars())

    def end_gcode(self):
        """What a finished print ends with: ``gcode.end``, then ``gcode.clear_bed`` under
        :data:`CLEAR_BED_MARK` when the bed clears by itself (``bed_clear: auto``)."""
        end = self.render_gcode("end")
        if self.bed_clear != "auto":
            return end
        return end.rstrip("\n") + "\n" + CLEAR_BED_MARK + "\n" + self.render_gcode("clear_bed")


def _fmt(v):
    """Numbers as G-code likes them: no trailing zeros, no exponent."""
    return ("%.4f" % v).rstrip("0").rstrip(".")
