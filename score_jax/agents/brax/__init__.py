"""The single-agent baselines of §5.1 trained by brax: SAC and PPO (``agents``), H-PPO
(``hppo`` + ``composite_dist``), with their transfer variants (``agents.variants``), and the
flat-action view of a composite environment brax trains on (``flat_env``); settings in
``config`` (``--single.*``). Importing ``config`` never imports brax."""
