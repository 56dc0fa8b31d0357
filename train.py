"""Train a learned matcher: ``python train.py fit --config configs/dispnet.yaml`` (see stereonet.cli.train)."""

from stereonet.cli.train import main

if __name__ == "__main__":
    main()
