"""The data_gen validation sets of the fused-cost experiments (seeds 5150/5151, not the benchmark's): ``val2``
(12 pairs, difficulty 2) and ``val4`` (8 pairs, difficulty 4); ``val2b``/``val4b`` the same sizes on seeds 5152/5153
(first used by the seventeenth session's confirmation of sgm-refine-choose), ``val2c``/``val4c`` on seeds 5154/5155
(its resumed run), ``val2d``/``val4d`` on seeds 5156/5157 (the three-map run), ``val2e``/``val4e`` on
seeds 5158/5159 (the eighteenth session's left-right fallback), ``val2f``/``val4f`` on seeds 5160/5161 (its census
evidence run), ``val2g``/``val4g`` on seeds 5162/5163 (the nineteenth session's 192x384 training renders), ``val2h``/``val4h`` on
seeds 5164/5165 (the twentieth session's SGM-loss fine-tuning), ``val2i``/``val4i`` on seeds 5166/5167 (its chooser
trained with each pair's own range), ``val2j``/``val4j`` on seeds 5168/5169 (the twenty-first session's
adaptive mix), ``val2k``/``val4k`` on seeds 5172/5173 (the twenty-third session's SGA probe), ``shm32`` (32 pairs,
seed 5174, difficulty 2, ``shared_material=0.5``: the twenty-fifth session's same-look depth edges) and ``shm32b`` (the same on seed
5175: its fused-weight probe), ``shm32-plain`` (shm32's pairs without the shared looks: the same geometry, for a
paired comparison), ``val2l``/``val4l`` on seeds 5176/5177 (the twenty-sixth session's census-input tower), ``val2m``/``val4m`` on seeds
5178/5179 (the twenty-seventh session's learned penalties), ``val2n``/``val4n`` on seeds 5180/5181 (the
twenty-eighth session's graphcut label pruning), ``prior2``/``prior4`` (12 pairs each, seeds 5182/5183: the
chooser's class prior) ``val2o``/``val4o`` on seeds 5184/5185 (its prior-corrected choice) and ``val2p``/``val4p`` on seeds 5186/5187 (its
depth-edge Siamese run), ``val2q``/``val4q`` on seeds 5188/5189 (graphcut pruning with sgm's proposals), ``val2r``/``val4r`` on seeds
5190/5191 (the depth-edge run of the shipped Siamese recipe), ``val2s``/``val4s`` on seeds 5192/5193 (graphcut's
lighter pruning), ``val2t``/``val4t`` on seeds 5194/5195 (the depth-edge run at share 0.25), ``val2u``/``val4u`` on seeds 5196/5197 (the
twenty-ninth session's added depth-edge samples), ``tex2``/``tex4`` (12 / 8 pairs, seeds 5198/5199, difficulty 2 / 4 with
every surface textured: the level's texture mix without ``weak`` and ``flat``; its textured-interior diagnostic),
``val2v``/``val4v`` on seeds 5200/5201 and ``tex2v``/``tex4v`` (textured as tex2/tex4) on seeds 5202/5203 (its
textured-training run), ``val2w``/``val4w`` on seeds 5204/5205 (the thirtieth session's width-16 tower for
speed), ``val2x``/``val4x`` on seeds 5206/5207 (its refine.pt retrained on that tower), ``val2y``/``val4y`` on seeds 5208/5209 (its width-16 run at
edge share 0.75), ``val2z``/``val4z`` on seeds 5210/5211 (its 8-channel chooser), ``val2aa``/``val4aa`` on seeds 5212/5213 (the
thirty-first session's cross-cost chooser), ``unc2``/``unc4`` on seeds 5214/5215 (its SMD uncertainty probe),
``val2ab``/``val4ab`` on seeds 5216/5217 and ``wb2``/``wb4`` (every scene's background walls weakly textured,
``weak_background=1``) on seeds 5218/5219 (its weak-background chooser), ``val2ac``/``val4ac`` on seeds
5220/5221 and ``wb2b``/``wb4b`` on seeds 5222/5223 (its weak-background Siamese tower), ``val2ad``/``val4ad`` on seeds
5224/5225 and ``wb2c``/``wb4c`` on seeds 5226/5227 (the thirty-second session's class-balanced chooser), ``wsel2``/``wsel4``
on seeds 5228/5229 and ``wselb2``/``wselb4`` (weak_background 1) on seeds 5230/5231 (its weighted-median selection),
``wmf2``/``wmf4`` on seeds 5232/5233 and ``wmfb2``/``wmfb4`` (weak_background 1) on seeds 5234/5235 (its
confirmation), ``val2ae``/``val4ae`` on seeds 5236/5237 and ``wb2d``/``wb4d`` (weak_background 1) on seeds 5238/5239
(the chooser on filtered maps), ``val2af``/``val4af`` on seeds 5240/5241 and ``wb2e``/``wb4e`` (weak_background 1) on
seeds 5242/5243 (the smaller weighted median for speed), ``val2ag``/``val4ag`` on seeds 5244/5245 and ``wb2f``/``wb4f``
(weak_background 1) on seeds 5246/5247 (the chooser with only sgm's map filtered), ``val2ah``/``val4ah`` on seeds
5248/5249 and ``wb2g``/``wb4g`` (weak_background 1) on seeds 5250/5251 (a chooser trained on sgm's filtered map),
``val2ai``/``val4ai`` on seeds 5252/5253 and ``wb2h``/``wb4h`` (weak_background 1) on seeds 5254/5255 (the thirty-third
session's strided weighted median: selection), ``val2aj``/``val4aj`` on seeds 5256/5257 and ``wb2i``/``wb4i``
(weak_background 1) on seeds 5258/5259 (its confirmation), ``val2ak``/``val4ak`` on seeds 5260/5261 and ``wb2j``/``wb4j``
(weak_background 1) on seeds 5262/5263 (the second candidate's confirmation), ``val2al``/``val4al`` on seeds 5264/5265
and ``wb2k``/``wb4k`` (weak_background 1) on seeds 5266/5267 (the census pre-filter: selection), ``val2am``/``val4am``
on seeds 5268/5269 and ``wb2l``/``wb4l`` (weak_background 1) on seeds 5270/5271 (its confirmation), ``hires2``
(6 pairs at 512x1024, seed 5272, difficulty 2: a diagnostic of the matchers at twice the renders' usual size),
``val2an``/``val4an`` on seeds 5273/5274 (the thirty-fourth session's wider DispNet reach), ``val2ap``/``val4ap`` on
seeds 5277/5278 (its dilated 3-D aggregation; 5275/5276 were set aside for a run that did not happen),
``val2ar``/``val4ar`` on seeds 5281/5282 (the thirty-fifth session's matched fine read-out; 5279/5280 were set aside
for a run that did not happen), ``val2as``/``val4as`` on seeds 5283/5284 (its conditional long run, which did not
run: never rendered), ``val2at``/``val4at`` on seeds 5285/5286 (dispnet's left-right check) and ``val2au``/``val4au``
on seeds 5287/5288 (dispnet trained on non-occluded pixels), ``val2av``/``val4av`` on seeds 5289/5290 (the
thirty-sixth session's shipped recipe trained on non-occluded pixels), ``val2aw``/``val4aw`` on seeds 5291/5292 (its
left-right check for smd), ``val2ax``/``val4ax`` on seeds 5293/5294 (its second rule: rejected pixels scored by the
mixture), ``val2ay``/``val4ay`` on seeds 5295/5296 (smd's head on the new dispnet.pt), ``val2az``/``val4az`` and
``wb2m``/``wb4m`` on seeds 5297-5300 (the thirty-seventh session's weighted median after dispnet), ``val2ba``/``val4ba``
and ``wb2n``/``wb4n`` on seeds 5301-5304 (the same after smd), ``val2bb``/``val4bb`` on seeds 5305/5306 (dispnet
trained on anti-aliased renders), ``val2bc``/``val4bc`` and ``wb2o``/``wb4o`` on seeds 5307-5310 (smd's head on
the shipped dispnet.pt, tested again), ``val2bd``/``val4bd``/``wb2p``/``wb4p`` and ``val2be``/``val4be``/``wb2q``/``wb4q``
on seeds 5311-5318 (dispnet's weighted-median window: selection; the confirmation sets were never rendered),
``val2bf``/``val4bf``/``wb2r``/``wb4r`` on seeds 5319-5322 (the thirty-eighth session's windows of larger renders)
and ``val2bg``/``val4bg``/``wb2s``/``wb4s`` on seeds 5323-5326 (its shipped-recipe run), ``pow2``/``pow4``/``powb2``/``powb4``
(64 pairs each, difficulties 2 / 4, the last two with every background wall weakly textured) on seeds 5327-5330 (the
thirty-ninth session's powered DispNet decision, docs/experiments/dispnet_powered.txt) and ``pow2c``/``pow4c``/``powb2c``/``powb4c``
the same on seeds 5331-5334 (its 4x-schedule run, docs/experiments/dispnet_long4x.txt) and ``pow2d``/``pow4d``/
``powb2d``/``powb4d`` the same on seeds 5335-5338 (the fortieth session's pooled full-resolution volume,
docs/experiments/dispnet_pooled.txt) and ``pow2e``/``pow4e``/``powb2e``/``powb4e`` the same on seeds 5339-5342 (smd's
head on the 4x-schedule dispnet.pt, docs/experiments/smd_head_4x.txt) and ``pow2f``/``pow4f``/``powb2f``/``powb4f`` the
same on seeds 5343-5346 (its edge-weighted head, docs/experiments/smd_head_edge.txt) and ``pow2g``/``pow4g``/
``powb2g``/``powb4g`` the same on seeds 5347-5350 (the 8x-schedule DispNet, docs/experiments/dispnet_long8x.txt) and
``pow2h``/``pow4h``/``thn2h``/``thn4h`` (64 pairs each, difficulties 2 / 4, the last two with thin rods in every scene,
``thin_structures: 1``) on seeds 5351-5354 (the forty-third session's thin structures, docs/experiments/dispnet_thin.txt)
and ``pow2i``/``pow4i``/``powb2i``/``powb4i`` as the ``g`` sets on seeds 5355-5358 (smd's head on the 8x-schedule
DispNet, docs/experiments/smd_head_8x.txt); any
other spec as
eval.py reads it. ``compare``
runs named variants of a matcher on them and prints the table and each pair's bad-2."""
import functools

import data_gen
from data_gen.scene import MAX_DIFFICULTY, texture_mix
from stereonet.data import _SyntheticItems, load_dataset

TEXTURED = {level: texture_mix(level, ("weak", "flat")) for level in range(MAX_DIFFICULTY + 1)}
"""Each difficulty's texture mix without the kinds chosen for their lack of texture."""

SETS = {"val2": (12, 5150, 2), "val4": (8, 5151, 4), "val2b": (12, 5152, 2), "val4b": (8, 5153, 4),
        "val2c": (12, 5154, 2), "val4c": (8, 5155, 4), "val2d": (12, 5156, 2), "val4d": (8, 5157, 4),
        "val2e": (12, 5158, 2), "val4e": (8, 5159, 4), "val2f": (12, 5160, 2), "val4f": (8, 5161, 4),
        "val2g": (12, 5162, 2), "val4g": (8, 5163, 4), "val2h": (12, 5164, 2), "val4h": (8, 5165, 4),
        "val2i": (12, 5166, 2), "val4i": (8, 5167, 4),
        "val2j": (12, 5168, 2), "val4j": (8, 5169, 4),
        "val2k": (12, 5172, 2), "val4k": (8, 5173, 4), "shm32": (32, 5174, 2, {"shared_material": 0.5}),
        "shm32b": (32, 5175, 2, {"shared_material": 0.5}), "shm32-plain": (32, 5174, 2),
        "val2l": (12, 5176, 2), "val4l": (8, 5177, 4), "val2m": (12, 5178, 2), "val4m": (8, 5179, 4),
        "val2n": (12, 5180, 2), "val4n": (8, 5181, 4), "prior2": (12, 5182, 2), "prior4": (12, 5183, 4),
        "val2o": (12, 5184, 2), "val4o": (8, 5185, 4), "val2p": (12, 5186, 2), "val4p": (8, 5187, 4),
        "val2q": (12, 5188, 2), "val4q": (8, 5189, 4), "val2r": (12, 5190, 2), "val4r": (8, 5191, 4),
        "val2s": (12, 5192, 2), "val4s": (8, 5193, 4),
        "val2t": (12, 5194, 2), "val4t": (8, 5195, 4),
        "val2u": (12, 5196, 2), "val4u": (8, 5197, 4),
        "tex2": (12, 5198, 2, {"textures": TEXTURED[2]}), "tex4": (8, 5199, 4, {"textures": TEXTURED[4]}),
        "val2v": (12, 5200, 2), "val4v": (8, 5201, 4),
        "tex2v": (12, 5202, 2, {"textures": TEXTURED[2]}), "tex4v": (8, 5203, 4, {"textures": TEXTURED[4]}),
        "val2w": (12, 5204, 2), "val4w": (8, 5205, 4),
        "val2x": (12, 5206, 2), "val4x": (8, 5207, 4),
        "val2y": (12, 5208, 2), "val4y": (8, 5209, 4),
        "val2z": (12, 5210, 2), "val4z": (8, 5211, 4),
        "val2aa": (12, 5212, 2), "val4aa": (8, 5213, 4),
        "unc2": (12, 5214, 2), "unc4": (8, 5215, 4),
        "val2ab": (12, 5216, 2), "val4ab": (8, 5217, 4),
        "wb2": (12, 5218, 2, {"weak_background": 1.0}), "wb4": (8, 5219, 4, {"weak_background": 1.0}),
        "val2ac": (12, 5220, 2), "val4ac": (8, 5221, 4),
        "wb2b": (12, 5222, 2, {"weak_background": 1.0}), "wb4b": (8, 5223, 4, {"weak_background": 1.0}),
        "val2ad": (12, 5224, 2), "val4ad": (8, 5225, 4),
        "wb2c": (12, 5226, 2, {"weak_background": 1.0}), "wb4c": (8, 5227, 4, {"weak_background": 1.0}),
        "wsel2": (12, 5228, 2), "wsel4": (8, 5229, 4),
        "wselb2": (12, 5230, 2, {"weak_background": 1.0}), "wselb4": (8, 5231, 4, {"weak_background": 1.0}),
        "wmf2": (12, 5232, 2), "wmf4": (8, 5233, 4),
        "wmfb2": (12, 5234, 2, {"weak_background": 1.0}), "wmfb4": (8, 5235, 4, {"weak_background": 1.0}),
        "val2ae": (12, 5236, 2), "val4ae": (8, 5237, 4),
        "wb2d": (12, 5238, 2, {"weak_background": 1.0}), "wb4d": (8, 5239, 4, {"weak_background": 1.0}),
        "val2af": (12, 5240, 2), "val4af": (8, 5241, 4),
        "wb2e": (12, 5242, 2, {"weak_background": 1.0}), "wb4e": (8, 5243, 4, {"weak_background": 1.0}),
        "val2ag": (12, 5244, 2), "val4ag": (8, 5245, 4),
        "wb2f": (12, 5246, 2, {"weak_background": 1.0}), "wb4f": (8, 5247, 4, {"weak_background": 1.0}),
        "val2ah": (12, 5248, 2), "val4ah": (8, 5249, 4),
        "wb2g": (12, 5250, 2, {"weak_background": 1.0}), "wb4g": (8, 5251, 4, {"weak_background": 1.0}),
        "val2ai": (12, 5252, 2), "val4ai": (8, 5253, 4),
        "wb2h": (12, 5254, 2, {"weak_background": 1.0}), "wb4h": (8, 5255, 4, {"weak_background": 1.0}),
        "val2aj": (12, 5256, 2), "val4aj": (8, 5257, 4),
        "wb2i": (12, 5258, 2, {"weak_background": 1.0}), "wb4i": (8, 5259, 4, {"weak_background": 1.0}),
        "val2ak": (12, 5260, 2), "val4ak": (8, 5261, 4),
        "wb2j": (12, 5262, 2, {"weak_background": 1.0}), "wb4j": (8, 5263, 4, {"weak_background": 1.0}),
        "val2al": (12, 5264, 2), "val4al": (8, 5265, 4),
        "wb2k": (12, 5266, 2, {"weak_background": 1.0}), "wb4k": (8, 5267, 4, {"weak_background": 1.0}),
        "val2am": (12, 5268, 2), "val4am": (8, 5269, 4),
        "wb2l": (12, 5270, 2, {"weak_background": 1.0}), "wb4l": (8, 5271, 4, {"weak_background": 1.0}),
        "hires2": (6, 5272, 2, {"height": 512, "width": 1024}),
        "val2an": (12, 5273, 2), "val4an": (8, 5274, 4),
        "val2ap": (12, 5277, 2), "val4ap": (8, 5278, 4),
        "val2ar": (12, 5281, 2), "val4ar": (8, 5282, 4), "val2as": (12, 5283, 2), "val4as": (8, 5284, 4),
        "val2at": (12, 5285, 2), "val4at": (8, 5286, 4), "val2au": (12, 5287, 2), "val4au": (8, 5288, 4),
        "val2av": (12, 5289, 2), "val4av": (8, 5290, 4), "val2aw": (12, 5291, 2), "val4aw": (8, 5292, 4),
        "val2ax": (12, 5293, 2), "val4ax": (8, 5294, 4), "val2ay": (12, 5295, 2), "val4ay": (8, 5296, 4),
        "val2az": (12, 5297, 2), "val4az": (8, 5298, 4),
        "wb2m": (12, 5299, 2, {"weak_background": 1.0}), "wb4m": (8, 5300, 4, {"weak_background": 1.0}),
        "val2ba": (12, 5301, 2), "val4ba": (8, 5302, 4),
        "wb2n": (12, 5303, 2, {"weak_background": 1.0}), "wb4n": (8, 5304, 4, {"weak_background": 1.0}),
        "val2bb": (12, 5305, 2), "val4bb": (8, 5306, 4),
        "val2bc": (12, 5307, 2), "val4bc": (8, 5308, 4),
        "wb2o": (12, 5309, 2, {"weak_background": 1.0}), "wb4o": (8, 5310, 4, {"weak_background": 1.0}),
        "val2bd": (12, 5311, 2), "val4bd": (8, 5312, 4),
        "wb2p": (12, 5313, 2, {"weak_background": 1.0}), "wb4p": (8, 5314, 4, {"weak_background": 1.0}),
        "val2be": (12, 5315, 2), "val4be": (8, 5316, 4),
        "wb2q": (12, 5317, 2, {"weak_background": 1.0}), "wb4q": (8, 5318, 4, {"weak_background": 1.0}),
        "val2bf": (12, 5319, 2), "val4bf": (8, 5320, 4),
        "wb2r": (12, 5321, 2, {"weak_background": 1.0}), "wb4r": (8, 5322, 4, {"weak_background": 1.0}),
        "val2bg": (12, 5323, 2), "val4bg": (8, 5324, 4),
        "wb2s": (12, 5325, 2, {"weak_background": 1.0}), "wb4s": (8, 5326, 4, {"weak_background": 1.0}),
        "pow2": (64, 5327, 2), "pow4": (64, 5328, 4),
        "powb2": (64, 5329, 2, {"weak_background": 1.0}), "powb4": (64, 5330, 4, {"weak_background": 1.0}),
        "pow2c": (64, 5331, 2), "pow4c": (64, 5332, 4),
        "powb2c": (64, 5333, 2, {"weak_background": 1.0}), "powb4c": (64, 5334, 4, {"weak_background": 1.0}),
        "pow2d": (64, 5335, 2), "pow4d": (64, 5336, 4),
        "powb2d": (64, 5337, 2, {"weak_background": 1.0}), "powb4d": (64, 5338, 4, {"weak_background": 1.0}),
        "pow2e": (64, 5339, 2), "pow4e": (64, 5340, 4),
        "powb2e": (64, 5341, 2, {"weak_background": 1.0}), "powb4e": (64, 5342, 4, {"weak_background": 1.0}),
        "pow2f": (64, 5343, 2), "pow4f": (64, 5344, 4),
        "powb2f": (64, 5345, 2, {"weak_background": 1.0}), "powb4f": (64, 5346, 4, {"weak_background": 1.0}),
        "pow2g": (64, 5347, 2), "pow4g": (64, 5348, 4),
        "powb2g": (64, 5349, 2, {"weak_background": 1.0}), "powb4g": (64, 5350, 4, {"weak_background": 1.0}),
        "pow2h": (64, 5351, 2), "pow4h": (64, 5352, 4),
        "thn2h": (64, 5353, 2, {"thin_structures": 1.0}), "thn4h": (64, 5354, 4, {"thin_structures": 1.0}),
        "pow2i": (64, 5355, 2), "pow4i": (64, 5356, 4),
        "powb2i": (64, 5357, 2, {"weak_background": 1.0}), "powb4i": (64, 5358, 4, {"weak_background": 1.0})}
"""spec -> (pairs, seed, difficulty[, render options])."""


def expand(arg):
    """The specs of a ``"val2;val4;real"`` argument, ``real`` as its datasets (eval.py's expansion)."""
    from stereonet.evaluation import expand_data_specs

    return [s for spec in arg.split(";") for s in (expand_data_specs(spec) if spec == "real" else [spec])]


def items(specs):
    """``(spec, item)`` for every pair of every spec in ``specs``, in order."""
    for spec in specs:
        ds = load(spec)
        for i in range(len(ds)):
            yield spec, ds[i]


def load(spec):
    if spec in SETS:
        count, seed, difficulty, *options = SETS[spec]
        return _SyntheticItems(data_gen.SyntheticStereo(count=count, seed=seed, difficulty=difficulty,
                                                        **(options[0] if options else {})), spec)
    return load_dataset(spec)


def compare(variants, specs):
    """``variants``: {name: (matcher function, its options)}, each registered under ``name`` and evaluated with
    eval.py's fill on ``specs`` (e.g. ``["val2", "val4"]`` or ``["real"]``)."""
    from stereonet.evaluation import format_table, run_evaluation
    from stereonet.matchers import register

    for name, (fn, options) in variants.items():
        register(name, kind="learned", description="exp")(functools.partial(fn, **options))
    ev = run_evaluation(list(variants), specs, fill=True, progress=False, load=load)
    print(format_table(ev.rows))
    for p in ev.pairs:
        print("PAIR", p.method, p.dataset, p.pair, None if p.metrics is None else round(p.metrics["bad2"], 3))
